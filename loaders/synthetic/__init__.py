"""Synthetic stand-ins for BigBIRD and AVD, written in the real on-disk formats.

- ``textures``: the 12 procedural source-domain texture families (classifier categories);
- ``objects``: the instances (convex prisms shaped like the real objects, faces painted with
  the families, some face textures shared between instances) and the embedded AVD instance map;
- ``render``: the numpy/OpenCV renderer both writers use;
- ``bigbird_writer``: object folders with calibration, turntable poses, JPEGs and P4 masks;
- ``nuisance``: the BigBIRD rig's nuisance (sensor noise, exposure/white balance, decentred and
  wobbling object, mask errors);
- ``scene``: the AVD rooms (furniture, placements, clutter, occluders, capture grid; one per scan)
  and which instances each scan holds;
- ``avd_writer``: one AVD scan (images with auto-exposure, motion blur and noise, jittered boxes,
  annotations.json, image_structs.mat, ...);
- ``source_domain``: the classifier's synthetic training domain (texture-family crops), rendered
  in worker processes by the classifier stage.

The ``data`` stage (``stages/data.py``) drives the writers.
"""
