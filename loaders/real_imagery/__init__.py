"""``data.source = "real_imagery"``: real COIL-100 photographs on real AVD robot geometry, written
in the BigBIRD and AVD formats the other stages read (docs/real_data.md).

- ``pairing``: the real AVD boxes of each scan, each instance located from its real rays, and the
  seeded pairing of located instances with COIL objects and yaws (the one synthetic part);
- ``frames``: pure functions from a real camera pose to the held-out COIL view it sees, resampled
  to the real box and passed through the sensor model;
- ``training``: the COIL training views as BigBIRD object folders;
- ``write``: the data stage's writer for this source (both sides, truth.json);
- ``category`` and ``clutter``: ``dataset = "eth80"``, category classes with instance folds and
  the test objects cut out over black or real AVD clutter.
"""
