"""Instance labels from the features table: a class made of several object folders (ETH-80's
category folds) keeps each view's folder as its instance, and the bank-like fit of the instance
term's provider (``fit_from_features(fit=...)`` through ``fit_with_term``) fits the term on exactly
the fold's member objects."""
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.banks.model_bank import fit_from_features, read_training_views
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.methods.instance_term import fit_with_term
from tests.stages.test_models_stage import mcfg, write_features

OBJECTS = ["eth80_cup1", "eth80_cup2", "eth80_cup3", "eth80_dog1", "eth80_dog2", "eth80_dog3"]
# Fold 3 holds out instance 3 of each category; "pear__f1" is a class of one object.
MEMBERS = {"cup__f3": ["eth80_cup1", "eth80_cup2"], "dog__f3": ["eth80_dog1", "eth80_dog2"],
           "pear__f1": ["eth80_cup3"]}


def write(path):
    """The tiny features table with ETH-80 view codes (360 x instance + azimuth: unique per class)."""
    write_features(path, classes=OBJECTS, n_angles=12)
    t = pq.read_table(path)
    inst = np.array([int(o[-1]) for o in t.column("object").to_pylist()])
    codes = pa.array(t.column("angle_deg").to_numpy() + 360 * inst, pa.int32())
    pq.write_table(t.set_column(t.schema.get_field_index("angle_deg"), "angle_deg", codes), path)


def test_views_keep_their_object_folder(tmp_path):
    write(tmp_path / "bigbird.parquet")
    cols, _, _, _ = read_training_views(tmp_path / "bigbird.parquet", 1, MEMBERS)
    for cls, objs in MEMBERS.items():
        rows = cols["object"] == cls
        assert sorted(set(cols["member"][rows])) == objs
        assert np.array_equal(cols["angle_deg"][rows] // 360, [int(m[-1]) for m in cols["member"][rows]])
    plain, _, _, _ = read_training_views(tmp_path / "bigbird.parquet", 1)   # no classes of members
    assert np.array_equal(plain["member"], plain["object"])


def test_instance_bank_fits_on_the_fold_members_only(tmp_path):
    write(tmp_path / "bigbird.parquet")
    models, extra = fit_with_term(lambda fit: fit_from_features(tmp_path / "bigbird.parquet", mcfg(classes="all",
                                                                restarts=0), progress=False, class_members=MEMBERS,
                                                                fit=fit))
    assert isinstance(models, InstanceGPClassModels)
    assert extra["instances"] == {c: sorted(m) for c, m in MEMBERS.items()}
    by_class = {}
    for d in extra["diagnostics"]:
        by_class.setdefault(d["class"], []).append(d)
    assert all(d["instance_term"] and d["n_instances"] == 2 for c in ("cup__f3", "dog__f3") for d in by_class[c])
    assert all(not d["instance_term"] and d["instance_amplitude"] == 0 for d in by_class["pear__f1"])
    c = models.classes.index("cup__f3")
    assert len(models.X[c]) == 24 and sorted(set(models.instances[c].tolist())) == [0, 1]
