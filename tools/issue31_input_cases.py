"""Issue 31 (compare's reads, configs, inputs): each case's message, one line per case.

``PYTHONPATH=<tree> python tools/issue31_input_cases.py`` (the tree's tests/ supply the fixture
helpers); ``SKIP="name,name"`` skips cases by name (on an older tree the /dev/zero and FIFO
cases would eat memory or hang). Writes only under a temporary folder."""
import contextlib, io, json, os, sys, tempfile, traceback
from pathlib import Path
import numpy as np

TREE = Path(os.environ["PYTHONPATH"])
sys.path.insert(0, str(TREE))
sys.setrecursionlimit(1000)
from tests.stages.commands.test_compare import write_run  # noqa
from stages.commands.cli import main  # noqa

skip = set(os.environ.get("SKIP", "").split(","))


def cli(args):
    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main(args)
    except BaseException as e:  # noqa
        return f"raised {type(e).__name__}: {str(e)[:150]}"
    text = (err.getvalue().strip().splitlines() or [""])[-1]
    return f"exit {rc}: {text[:230]}"


def call(f):
    try:
        r = f()
        return f"ok: {str(r)[:200]}"
    except BaseException as e:  # noqa
        return f"{type(e).__name__}: {str(e)[:230]}"


def case(name, fn):
    if name in skip:
        print(f"{name} | (skipped on this tree)")
        return
    print(f"{name} | {fn()}", flush=True)


T = Path(tempfile.mkdtemp())
n = [0]


def run(edit=None):
    n[0] += 1
    r = write_run(T / f"r{n[0]}" / "a")
    if edit:
        edit(r)
    return r


def summ(r):
    return r / "evaluate" / "summary.json"


def edit_pop(change):
    def e(r):
        s = json.loads(summ(r).read_text()); change(s["population"]); summ(r).write_text(json.dumps(s))
    return e


def dz(r):
    summ(r).unlink(); os.symlink("/dev/zero", summ(r))


def fifo(r):
    summ(r).unlink(); os.mkfifo(summ(r))


case("compare: summary.json -> /dev/zero", lambda: cli(["compare", str(run(dz))]))
case("compare: summary.json a FIFO", lambda: cli(["compare", str(run(fifo))]))
case("compare: verdict row without comparison", lambda: cli(["compare", str(run(edit_pop(lambda p: p["verdict_table"][0].pop("comparison"))))]))
case("compare: verdict_table = [1, 2]", lambda: cli(["compare", str(run(edit_pop(lambda p: p.__setitem__("verdict_table", [1, 2]))))]))
case("compare: pooled.with_uncertainty = 5", lambda: cli(["compare", str(run(edit_pop(lambda p: p["pooled"].__setitem__("with_uncertainty", 5))))]))
case("compare: summary nested 100,000 deep", lambda: cli(["compare", str(run(lambda r: summ(r).write_text("[" * 100000 + "]" * 100000)))]))


def manifest(value):
    def go():
        a, b = run(), run(lambda r: (r / "models" / "manifest.json").write_text(json.dumps(value)))
        err, out = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                rc = main(["compare", str(a), str(b), "--out", str(T / "cmp")])
        except BaseException as e:  # noqa
            return f"raised {type(e).__name__}: {e}"
        lines = out.getvalue().splitlines() or [""]
        notes = [l for l in lines if "manifest" in l and "unreadable" in l]
        return f"exit {rc}: {lines[0][:90]} {(notes[0][:200] if notes else '(no note)')} {err.getvalue().strip()[-150:]}"
    return go


case("compare: manifest parts.sections = [1, 2]", manifest({"parts": {"sections": [1, 2]}}))
case("compare: manifest = [1]", manifest([1]))


def escapes():
    a = run()
    b = run(lambda r: (r / "models" / "manifest.json").write_text(json.dumps(
        {"parts": {"sections": {"models": {"component_rule": "\x1b]0;owned\x07\x1b[2J"}}}})))
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        main(["compare", str(a), str(b), "--out", str(T / "cmp2")])
    line = next(l for l in out.getvalue().splitlines() if "owned" in l)
    return ("raw ESC in output: " + repr(line)) if "\x1b" in line else "escaped: " + line


case("compare: terminal escapes in a config value", escapes)

# -- configs
DEFAULT = TREE / "configs" / "synthetic.toml"


def out_of_tree():
    d = T / "elsewhere"; d.mkdir(exist_ok=True)
    (d / "mine.toml").write_text(f'extends = "{DEFAULT}"\n[run]\nname = "mine"\n')
    from pipeline.infra.config import load_config
    return f"run dir {load_config(d / 'mine.toml').run_dir}"


case("config: out-of-tree config extends the default", lambda: call(out_of_tree))


def chain():
    d = T / "chain"; d.mkdir(exist_ok=True)
    for i in range(1200):
        (d / f"c{i}.toml").write_text(f'extends = "c{i + 1}.toml"\n' if i < 1199 else "")
    return cli(["status", "--config", str(d / "c0.toml")])


case("config: 1,200-file extends chain", chain)


def deep():
    p = T / "deep.toml"; p.write_text("v = " + "[" * 100000 + "]" * 100000 + "\n")
    return cli(["status", "--config", str(p)])


case("config: value nested 100,000 deep", deep)

# -- inputs
from pipeline.method.gp_files import save_bank  # noqa
from pipeline.banks.model_bank import ablation_dir  # noqa
from stages.evaluate import load_banks  # noqa
from tests.pipeline.method.test_gp import make_models  # noqa

ABL = "models.component_rule=top_mean"


def abl(entry):
    def go():
        rng = np.random.default_rng(0)
        m = T / f"bank{n[0]}" / "run" / "models"; n[0] += 1
        save_bank(make_models(rng), m, extra={"ablations": {ABL: "x"}})
        save_bank(make_models(rng), m.parent.parent / "elsewhere")
        i = json.loads((m / "index.json").read_text())
        i["ablations"][ABL] = str(m.parent.parent / "elsewhere") if entry == "abs" else entry
        (m / "index.json").write_text(json.dumps(i))
        banks, _ = load_banks(m, (ABL,))
        return f"loaded bank {ABL!r} from outside the run folder ({len(banks)} banks)"
    return lambda: call(go)


case("inputs: index ablations entry absolute", abl("abs"))
case("inputs: index ablations entry ../..", abl("../../elsewhere"))

import pyarrow as pa  # noqa
import pyarrow.parquet as pq  # noqa
from pipeline.scoring.features import build_table, schema  # noqa


def _table(kind, N=4):
    rng = np.random.default_rng(1)
    cols = {}
    for f in schema(kind, 3):
        name, t = f.name, f.type
        if name in ("pass", "scores"):
            continue
        if pa.types.is_string(t):
            cols[name] = np.array([f"{name}_{i % 2}" for i in range(N)])
        elif pa.types.is_boolean(t):
            cols[name] = np.ones(N, bool)
        elif pa.types.is_integer(t):
            cols[name] = np.arange(N) % 2 + 1
        else:
            cols[name] = rng.uniform(-1, 1, N)
    return build_table(kind, cols, rng.dirichlet(np.ones(3), N), rng.dirichlet(np.ones(3), (N, 2)))
from pipeline.banks.model_bank import read_training_views  # noqa
from pipeline.scoring.features import read_features  # noqa
try:
    from stages.evaluate import AVD_COLUMNS  # noqa
    rf = lambda p: read_features(p, "avd", AVD_COLUMNS)  # noqa
except ImportError:
    rf = read_features


def tab(kind, change, reader):
    def go():
        t = change(_table(kind))
        p = T / f"t{n[0]}" / f"{kind}.parquet"; n[0] += 1; p.parent.mkdir()
        pq.write_table(t, p)
        r = reader(p)
        return f"read without complaint ({type(r).__name__})"
    return lambda: call(go)


def rep(name, vals):
    return lambda t: t.set_column(t.column_names.index(name), name, pa.array(vals))


rows = 12
case("inputs: bigbird camera as strings", tab("bigbird", rep("camera", [str(i % 2 + 1) for i in range(rows)]), lambda p: read_training_views(p, 1)))
case("inputs: avd without heading", tab("avd", lambda t: t.drop_columns(["heading"]), rf))
case("inputs: avd without scan", tab("avd", lambda t: t.drop_columns(["scan"]), rf))
case("inputs: avd heading all NaN", tab("avd", rep("heading", [float("nan")] * rows), rf))
case("inputs: avd pass as strings", tab("avd", rep("pass", [str(i) for i in range(rows)]), rf))

from pipeline.scoring.weight_files import load_state_dict_file, num_classes_of  # noqa


def w(arrays, nc=False):
    def go():
        p = T / f"w{n[0]}.npz"; n[0] += 1
        np.savez(p, **arrays)
        s = load_state_dict_file(p)
        return num_classes_of(s, p) if nc else "loaded"
    return lambda: call(go)


case("weights: classifier.6.weight with 0 rows", w({"classifier.6.weight": np.zeros((0, 8), np.float32)}, nc=True))
case("weights: a string-dtype array", w({"classifier.6.weight": np.zeros((3, 8), np.float32), "classifier.6.bias": np.array(["a", "b", "c"])}))
case("weights: all-NaN weight", w({"classifier.6.weight": np.full((3, 8), np.nan, np.float32)}))


def nan_scores():
    from pipeline.scoring.features import build_table
    t = _table("avd")
    cols = {k: t.column(k).to_pylist()[::3] for k in t.column_names if k not in ("scores", "pass")}
    det = np.full((4, 3), np.nan)
    return f"table built with NaN scores ({build_table('avd', cols, det, None).num_rows} rows)"


case("features: NaN scores before writing", lambda: call(nan_scores))
