"""One content digest for every model bank (pipeline/method/bank_index.content_digest): the GP
banks, one GP of one, the instance-term banks and the Dirichlet banks all digest through it, a
saved and reloaded bank keeps its digest, and any changed number changes it."""
import ast
from pathlib import Path

import numpy as np

from pipeline.method.bank_index import content_digest
from pipeline.method.dirichlet import DirichletModels
from pipeline.method.gp_files import load_bank, save_bank
from tests.pipeline.method.test_gp import make_models

ROOT = Path(__file__).resolve().parents[3]
BANK_CODE = ("pipeline/method/gp.py", "pipeline/method/gp_instance.py", "pipeline/method/gp_files.py",
             "pipeline/method/dirichlet.py", "pipeline/banks/model_bank.py")


def test_parts_are_told_apart_by_kind_shape_and_order():
    a = np.arange(6.0)
    digests = {content_digest(a), content_digest(a.reshape(2, 3)), content_digest(a.astype(np.float32)),
               content_digest(a.tolist()), content_digest(a, {"k": 1}), content_digest({"k": 1}, a),
               content_digest({"k": 2}, a)}
    assert len(digests) == 7
    assert content_digest({"b": 1, "a": [1, 2]}) == content_digest({"a": [1, 2], "b": 1})
    assert content_digest(np.asfortranarray(a.reshape(2, 3))) == content_digest(a.reshape(2, 3))


def test_gp_and_dirichlet_banks_keep_their_digest_through_their_files(tmp_path):
    gp = make_models(np.random.default_rng(0))
    save_bank(gp, tmp_path / "gp")
    assert load_bank(tmp_path / "gp").digest() == gp.digest()
    other = make_models(np.random.default_rng(0))
    other.noise[1, 0] *= 1.0 + 1e-12
    assert other.digest() != gp.digest() and other.digest(0, 0) == gp.digest(0, 0)
    assert other.digest(1, 0) != gp.digest(1, 0)

    dm = DirichletModels(["a", "b", "c"], np.arange(1, 13, dtype=float).reshape(3, 4), floor=1e-5)
    dm.save(tmp_path / "dir")
    assert DirichletModels.load(tmp_path / "dir").fingerprint() == dm.fingerprint()
    assert DirichletModels(["a", "b", "c"], dm.theta, floor=2e-5).fingerprint() != dm.fingerprint()
    assert len(gp.digest()) == len(dm.fingerprint()) == 32          # one convention: blake2b-128 hex


def test_no_bank_module_hashes_on_its_own():
    """The bank modules digest only through content_digest (file checks use cache.sha256_file)."""
    for rel in BANK_CODE:
        tree = ast.parse((ROOT / rel).read_text())
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
        assert "hashlib" not in names, f"{rel}: hashes with hashlib; use bank_index.content_digest"
