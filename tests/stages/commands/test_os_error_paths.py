"""Every OS error names its path: a write (or a read) that fails with ENOSPC (or EIO, EDQUOT) raises no file
name of its own (write() and flush() never do; pyarrow's and numpy's writers neither), so the
atomic writer adds the file it was writing and the stage runner, for a write outside it, the
stage's folder. The full disk is simulated in each real writer's lowest Python-level call."""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.infra import cache
from pipeline.infra.outputs import MANIFEST
from stages.commands.cli import main
from tests.support import stage_fakes


def _full(*_a, **_k):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _write_parquet(target: Path) -> None:
    import pyarrow as pa

    from pipeline.scoring.features import write_table
    write_table(pa.table({"a": [1, 2]}), target)


def _write_npz(target: Path) -> None:
    with cache.atomic_path(target) as tmp, open(tmp, "wb") as f:
        np.savez(f, a=np.zeros(3))


def _write_page(target: Path) -> None:
    from reports.shared.html import HtmlReport
    HtmlReport("t").write(target)


# writer -> (a call of it, the lowest Python-level call a full disk makes fail)
WRITERS = {
    "write_bytes": (lambda t: cache.write_bytes(t, b"x"), "pathlib.Path.write_bytes"),
    "write_json": (lambda t: cache.write_json(t, {"a": 1}), "pathlib.Path.write_text"),
    "write_text": (lambda t: cache.write_text(t, "x"), "pathlib.Path.write_text"),
    "copy_file": (lambda t: cache.copy_file(__file__, t), "shutil.copyfile"),
    "parquet (pyarrow)": (_write_parquet, "pyarrow.parquet.write_table"),
    "npz (numpy)": (_write_npz, "numpy.savez"),
    "HTML page": (_write_page, "pathlib.Path.write_text"),
}


@pytest.mark.parametrize("name", sorted(WRITERS))
@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO, errno.EDQUOT])
def test_a_failed_write_names_the_file(tmp_path, monkeypatch, name, code):
    write, call = WRITERS[name]

    def failing(*a, **k):
        raise OSError(code, os.strerror(code))
    monkeypatch.setattr(call, failing)
    target = tmp_path / "out" / "file.bin"
    target.parent.mkdir()
    with pytest.raises(OSError) as e:
        write(target)
    assert e.value.errno == code and e.value.filename == str(target), e.value
    assert sorted(target.parent.iterdir()) == []   # the temporary file is gone too


class _FailingFile:
    """A file whose read() fails as a bad disk does: EIO, no file name."""

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False

    def read(self, *a):
        raise OSError(errno.EIO, os.strerror(errno.EIO))


@pytest.mark.parametrize("read", ["sha256_file", "read_json"])
def test_a_failed_read_names_the_file(tmp_path, monkeypatch, read):
    from pipeline.infra.outputs import read_json

    p = tmp_path / "in.json"
    p.write_text("{}")
    monkeypatch.setattr(cache, "open", lambda *a, **k: _FailingFile(), raising=False)  # shadows the builtin there
    monkeypatch.setattr("pathlib.Path.read_text", lambda self, *a, **k: _FailingFile().read())
    with pytest.raises(OSError) as e:
        cache.sha256_file(p) if read == "sha256_file" else read_json(p)
    assert e.value.errno == errno.EIO and e.value.filename == str(p)


def test_errors_with_their_own_file_or_no_errno_are_kept(tmp_path, monkeypatch):
    own = FileNotFoundError(errno.ENOENT, "gone", "/elsewhere/x")
    for err in (own, cache.OutsideFolderError("x: outside; refused")):
        def fail(*a, err=err, **k):
            raise err
        monkeypatch.setattr("pathlib.Path.write_bytes", fail)
        with pytest.raises(OSError) as e:
            cache.write_bytes(tmp_path / "y.bin", b"x")
        assert e.value is err


def _stage_writes(monkeypatch, write):
    return stage_fakes.install(monkeypatch, {"a": ()}, {"a": write})


def _line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("run folder:")]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_a_full_disk_in_a_stage_names_the_file(tmp_path, monkeypatch, capsys):
    """Through the CLI, as a user sees it: the file, the words and the errno code on one line."""
    _stage_writes(monkeypatch, lambda ctx: cache.write_bytes(ctx.out / "table.bin", b"x"))
    monkeypatch.setattr("pathlib.Path.write_bytes", _full)
    assert main(["a", "--set", f"run.artifacts={tmp_path / 'art'}"]) == 1
    line = _line(capsys)
    assert os.path.join(".a.tmp", "table.bin") in line, line
    assert "no space left on the device" in line and "(ENOSPC)" in line
    assert not any(p.name == ".a.tmp" for p in (tmp_path / "art").rglob("*"))


@pytest.mark.parametrize("where", ["in the stage", "marking the stage folder"])
def test_a_write_outside_the_atomic_writer_names_the_stage_folder(tmp_path, monkeypatch, capsys, where):
    def raw(ctx):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a library writing by itself would
    _stage_writes(monkeypatch, raw if where == "in the stage" else lambda ctx: None)
    if where != "in the stage":   # the runner's first write into the new folder
        monkeypatch.setattr("stages.framework.runner.mark_owned", raw)
    assert main(["a", "--set", f"run.artifacts={tmp_path / 'art'}"]) == 1
    line = _line(capsys)
    assert ".a.tmp" in line and str(tmp_path / "art") in line and "(ENOSPC)" in line, line
    assert not any(p.name == ".a.tmp" for p in (tmp_path / "art").rglob("*"))


def test_the_manifest_write_names_its_file(tmp_path, monkeypatch, capsys):
    """The runner's own write after the stage (its manifest) names its file too."""
    real = Path.write_text

    def full_on_manifest(self, data, *a, **k):
        if self.name.startswith(f".{MANIFEST}."):   # atomic_path's temporary name for it
            _full()
        return real(self, data, *a, **k)
    monkeypatch.setattr("pathlib.Path.write_text", full_on_manifest)
    _stage_writes(monkeypatch, lambda ctx: None)
    assert main(["a", "--set", f"run.artifacts={tmp_path / 'art'}"]) == 1
    line = _line(capsys)
    assert os.path.join(".a.tmp", MANIFEST) in line and "(ENOSPC)" in line, line
