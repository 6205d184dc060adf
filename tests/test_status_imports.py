"""``viewfuse status`` derives every stage's code fingerprint from the source files without
importing the packages (its speed goal is in tests/bench/bench_status.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "torchvision", "pandas", "matplotlib", "sklearn", "cv2", "h5py")


def test_status_imports_none_of_the_heavy_packages(tmp_path):
    code = ("import sys\nfrom stages.cli import main\n"
            f"rc = main(['status', '--set', 'run.artifacts={tmp_path}'])\n"
            f"print('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules))\nsys.exit(rc)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr
    assert "HEAVY []" in r.stdout, r.stdout


def test_module_files_are_found_by_path_without_importing():
    import stages.registry as registry

    assert registry._module_file("stages.models") == ROOT / "stages" / "models.py"
    assert registry._module_file("pipeline.infra") == ROOT / "pipeline" / "infra" / "__init__.py"
    assert registry._module_file("pipeline.nope") is None and registry._module_file("torch") is None
    assert registry.defines("stages.features", "extra_key") and registry.defines("stages.evaluate", "extra_key") is False
