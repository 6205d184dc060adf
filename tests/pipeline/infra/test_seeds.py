"""The one derivation of named random streams (pipeline/infra/seeds.py): equal in every process,
distinct for distinct names, the CRC-32 convention the grid and the real-imagery writers drew
their numbers with, and no other name-derived seed anywhere in the code."""
import ast
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from pipeline.infra import seeds

ROOT = Path(__file__).resolve().parents[3]
CODE = ("pipeline", "loaders", "stages", "reports", "viewfuse", "examples", "tools")
RNG_CALLS = {"default_rng", "SeedSequence", "RandomState", "Generator", "PCG64", "PCG64DXSM", "Philox",
             "MT19937", "SFC64", "manual_seed", "Random", "seed"}


def test_the_same_names_give_the_same_stream_in_another_process():
    here = seeds.stream(11, "Home_001_1", "target", 3, "with_uncertainty").random(5)
    code = ("from pipeline.infra import seeds; "
            "print(repr(seeds.stream(11, 'Home_001_1', 'target', 3, 'with_uncertainty').random(5).tolist()))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(ROOT), "PYTHONHASHSEED": "123", "PATH": ""})
    assert eval(out.stdout) == here.tolist()


def test_names_order_and_kind_each_change_the_stream():
    base = seeds.stream(0, "a", "b").random(4)
    for other in (seeds.stream(0, "b", "a"), seeds.stream(0, "a", "c"), seeds.stream(1, "a", "b"),
                  seeds.stream(0, "a"), seeds.stream(0, "a", "b", 1)):
        assert not np.array_equal(other.random(4), base)
    # SeedSequence pads with zeros: a trailing 0 adds nothing (the module says so; kept for the numbers)
    assert np.array_equal(seeds.stream(0, "a", "b", 0).random(4), base)


def test_the_grid_convention_is_kept_number_for_number():
    """Text names enter as CRC-32 of their UTF-8 bytes, integers as themselves: the streams the
    evaluation grid, planning and the real-imagery writers drew before this module existed."""
    old = np.random.default_rng([5, zlib.crc32(b"target_x"), 2, zlib.crc32(b"biased/0.5")]).random(6)
    assert np.array_equal(seeds.stream(5, "target_x", 2, "biased/0.5").random(6), old)
    assert seeds.key(5, "é", 7) == [5, zlib.crc32("é".encode()), 7]


@pytest.mark.parametrize("bad", [1.5, -1, True, None, b"x"])
def test_names_that_are_not_text_or_counts_are_refused(bad):
    with pytest.raises(TypeError, match="seeds"):
        seeds.stream(0, "a", bad)


def _dotted(node) -> str:
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return node.id if isinstance(node, ast.Name) else ""


def _name_derived(arg) -> str | None:
    """Why an RNG constructor's argument is derived from a name, or None: text, a formatted
    string, or any call but ``int`` or another constructor (checked on its own) inside it: a hash,
    a helper, ``.encode()``."""
    for n in ast.walk(arg):
        if isinstance(n, ast.Constant) and isinstance(n.value, (str, bytes)):
            return f"text {n.value!r}"
        if isinstance(n, ast.JoinedStr):
            return "a formatted string"
        if isinstance(n, ast.Call) and _dotted(n.func) != "int" and _dotted(n.func).split(".")[-1] not in RNG_CALLS:
            return f"a call to {_dotted(n.func) or 'an expression'}"
    return None


def _ad_hoc(arg) -> str | None:
    """Why an RNG constructor's argument is a derivation of its own, or None: a seed is handed on
    as it is (a name, an attribute, an integer, ``int(...)`` of one); a list of seed material
    (``[seed, 7]``) or arithmetic (``seed + 1``, ``2**31 - 1``) names a stream, which
    ``seeds.stream(seed, *names)`` does."""
    if isinstance(arg, ast.Call) and _dotted(arg.func) == "int" and len(arg.args) == 1:
        arg = arg.args[0]
    if isinstance(arg, (ast.List, ast.Tuple, ast.ListComp, ast.GeneratorExp)):
        return "a list of seed material (name the stream: seeds.stream(seed, *names))"
    if isinstance(arg, (ast.BinOp, ast.UnaryOp)):
        return "arithmetic on a seed (name the stream: seeds.stream(seed, *names))"
    return None


def offences(path: Path) -> list[str]:
    tree, out = ast.parse(path.read_text(), str(path)), []
    for n in ast.walk(tree):
        if isinstance(n, ast.alias) and n.name == "crc32" or (isinstance(n, ast.Attribute) and n.attr == "crc32"):
            out.append(f"{path}:{n.lineno if hasattr(n, 'lineno') else '?'}: crc32")
        if isinstance(n, ast.Call) and _dotted(n.func).endswith("from_bytes") and any(
                isinstance(c, ast.Attribute) and c.attr in ("digest", "hexdigest") for a in n.args for c in ast.walk(a)):
            out.append(f"{path}:{n.lineno}: a hash digest turned into an integer")
        if isinstance(n, ast.Call) and _dotted(n.func).split(".")[-1] in RNG_CALLS:
            for a in [*n.args, *(k.value for k in n.keywords)]:
                why = _name_derived(a) or _ad_hoc(a)
                if why:
                    out.append(f"{path}:{n.lineno}: {_dotted(n.func)} seeded from {why}")
    return out


def test_no_name_derived_or_ad_hoc_seed_outside_the_seeds_module():
    own = ROOT / "pipeline" / "infra" / "seeds.py"
    found = [o for d in CODE for p in sorted((ROOT / d).rglob("*.py")) if p != own for o in offences(p)]
    assert not found, "derive named streams with pipeline.infra.seeds.stream / key:\n" + "\n".join(found)


def test_the_walk_catches_each_kind_of_private_derivation(tmp_path):
    cases = {
        "np.random.default_rng([seed, zlib.crc32(name.encode())])": "crc32",
        "np.random.default_rng([seed, stable_int('room', scan)])": "call to stable_int",
        "np.random.SeedSequence([seed, hash(name)])": "call to hash",
        "np.random.default_rng(f'{seed}/{name}')": "formatted",
        "int.from_bytes(hashlib.sha256(b'x').digest()[:8], 'little')": "digest",
        "torch.manual_seed('7')": "text",
        "np.random.default_rng([seed, 7])": "list of seed material",
        "np.random.SeedSequence([seed, c, f, 46]).generate_state(1)": "list of seed material",
        "np.random.default_rng(int(seed) + 1)": "arithmetic",
    }
    for code, why in cases.items():
        f = tmp_path / "m.py"
        f.write_text(code + "\n")
        assert any(why in o for o in offences(f)), code
    ok = tmp_path / "ok.py"
    ok.write_text("np.random.default_rng(int(seed))\nseeds.stream(seed, 'a', scan, 2**31 - 1)\n"
                  "torch.manual_seed(seed)\nnp.random.RandomState(self.random_state)\n")
    assert offences(ok) == []
