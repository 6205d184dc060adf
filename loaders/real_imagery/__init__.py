"""``data.source = "real_imagery"``: real COIL-100 photographs on real AVD robot geometry, written
in the BigBIRD and AVD formats the other stages read (docs/real_data.md).

- ``pairing``: the real AVD boxes of each scan, each instance located from its real rays, and the
  seeded pairing of located instances with COIL objects and yaws (the one synthetic part);
- ``frames``: pure functions from a real camera pose to the held-out COIL view it sees, resampled
  to the real box and passed through the sensor model;
- ``training``: the COIL training views as BigBIRD object folders;
- ``scans``: the one scan writer every turntable source shares (frames at located instances, the
  AVD scan files, the view-error and box-fit summaries);
- ``write``: the COIL-100 writer (its reader, training folders and pairing; truth.json);
- ``turntable``: a source of your own made of its reader alone (docs/extending.md, A dataset);
- ``category`` and ``clutter``: ``dataset = "eth80"``, category classes with instance folds and
  the test objects cut out over black or real AVD clutter.
"""
