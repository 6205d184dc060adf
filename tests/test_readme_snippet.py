"""The README's "From Python" snippet runs as written: extracted from the README (its indented
code block) and run in a fresh interpreter, it prints a posterior over its two classes."""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def snippet(text: str) -> str:
    section = text.split("## From Python", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"\n\n((?:    .*\n)+)", section)
    assert block, "README 'From Python': no indented code block"
    return "\n".join(line[4:] for line in block.group(1).splitlines()) + "\n"


def test_the_readme_python_snippet_runs_as_written():
    code = snippet((ROOT / "README.md").read_text())
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600,
                         env={"PYTHONPATH": str(ROOT), "PATH": "", "OMP_NUM_THREADS": "1"})
    assert out.returncode == 0, out.stderr[-3000:]
    p = [float(x) for x in re.findall(r"[0-9.eE+-]+", out.stdout.strip().strip("[]"))]
    # numpy prints 8 significant digits: two probabilities sum to 1 within 2 x 5e-9
    assert len(p) == 2 and abs(sum(p) - 1) < 1e-8, out.stdout


def test_the_extraction_takes_the_first_code_block_of_the_section():
    text = "# x\n## From Python\n\n    a = 1\n    print(a)\n\nprose\n\n    b = 2\n## Next\n"
    assert snippet(text) == "a = 1\nprint(a)\n"
