"""Synthetic stand-ins for BigBIRD and AVD, written in the real on-disk formats.

- ``textures``: the 12 procedural source-domain texture families (classifier categories);
- ``objects``: the instances (convex prisms shaped like the real objects, faces painted with
  the families, some face textures shared between instances) and the embedded AVD instance map;
- ``render``: the numpy/OpenCV renderer both writers use;
- ``bigbird_writer``: object folders with calibration, turntable poses, JPEGs and P4 masks;
- ``scene``: the AVD room (furniture, placements, clutter, capture grid);
- ``avd_writer``: one AVD scan (images, annotations.json, image_structs.mat, ...).

The ``data`` stage (``stages/data.py``) drives the writers.
"""
