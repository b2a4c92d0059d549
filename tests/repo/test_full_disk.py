"""A full disk: every output is written whole or not at all, the cache only saves time, and
`slip` says so in one line. The disk is a real one: a 256 KiB tmpfs mounted in a private mount
namespace (`unshare`), filled by the command itself, so ENOSPC comes from the kernel."""
from __future__ import annotations

import errno
import os
import pickle
import shutil
import subprocess
import sys
import time

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip import cache
from incipient_slip.errors import EXIT_FAILURE, UsageError
from incipient_slip.paths import out_of_space, written_atomically


def _mount_prefix() -> list[str] | None:
    """A command prefix that runs a shell in a new mount namespace where it may mount, or None."""
    if shutil.which("unshare") is None:
        return None
    for prefix in (["unshare", "--mount"], ["unshare", "--user", "--map-root-user", "--mount"]):
        if subprocess.run([*prefix, "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                          capture_output=True).returncode == 0:
            return prefix
    return None


def on_a_full_disk(command: str, tmp_path, size: str = "256k") -> subprocess.CompletedProcess:
    """Runs `command` (a shell line; $D is the small disk) with a tmpfs of `size` mounted at $D."""
    prefix = _mount_prefix()
    if prefix is None:
        pytest.skip("no mount namespace here (unshare --mount, as root or in a user namespace)")
    disk = tmp_path / "disk"
    disk.mkdir()
    script = f'mount -t tmpfs -o size={size} tmpfs "$D" && {command}; echo "rc=$?"; ls -A "$D"/*'
    return subprocess.run([*prefix, "sh", "-c", script], env={**os.environ, "D": str(disk)},
                          capture_output=True, text=True, timeout=120)


def test_a_data_set_on_a_full_disk_is_one_line_exit_1_and_leaves_no_partial_file(tmp_path):
    done = on_a_full_disk(f'"{sys.executable}" -m incipient_slip.cli dataset --scene paper --series 4 '
                          '--seed 0 --out "$D/data" --workers 1', tmp_path)
    assert f"rc={EXIT_FAILURE}" in done.stdout, (done.stdout, done.stderr)
    lines = [line for line in done.stderr.splitlines() if "error" in line]
    assert len(lines) == 1 and "slip dataset: error: No space left on device" in lines[0], done.stderr
    assert "Traceback" not in done.stderr
    # no temporary series file is left to fill the disk, and no meta.json says "finished"
    listing = done.stdout.split("rc=")[1]
    assert ".tmp" not in listing and "meta.json" not in listing, listing


def test_written_atomically_keeps_the_old_file_and_removes_the_temporary_one_on_error(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text("old")
    with pytest.raises(OSError):
        with written_atomically(path) as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
    with written_atomically(path) as tmp:
        assert tmp.parent == path.parent and tmp.name.startswith(".") and tmp.suffix == ".json"
        tmp.write_text("new")
    assert path.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_out_of_space_is_enospc_and_edquot_only():
    assert out_of_space(OSError(errno.ENOSPC, "full")) and out_of_space(OSError(errno.EDQUOT, "quota"))
    assert not out_of_space(OSError(errno.EACCES, "denied")) and not out_of_space(ValueError("x"))


def test_a_cache_that_cannot_store_still_returns_the_result_and_warns_once(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache's folder should be")     # every store fails
    monkeypatch.setattr(cache, "_unstored", set())
    with cache.use(blocker):
        assert cache.cached("kind-a", "ab" * 32, lambda: 41) == 41
        assert cache.cached("kind-a", "cd" * 32, lambda: 42) == 42
    said = capsys.readouterr().err
    assert said.count("cache: a kind-a result was not stored") == 1, said


def test_a_cache_on_a_full_disk_still_returns_the_result(tmp_path):
    code = ("import numpy as np; from pathlib import Path; from incipient_slip import cache\n"
            "with cache.use(Path('$D') / 'cache'):\n"
            "    v = cache.cached('big', 'ef' * 32, lambda: np.ones(100_000))\n"
            "assert v.sum() == 100_000; print('ok')")
    done = on_a_full_disk(f'"{sys.executable}" -c "{code}"', tmp_path, size="64k")
    assert "ok" in done.stdout and "rc=0" in done.stdout, (done.stdout, done.stderr)
    assert "cache: a big result was not stored (No space left on device" in done.stderr
    assert ".tmp" not in done.stdout.split("rc=")[1]


def _entry(directory, name: str, size: int, age_s: float):
    """A cache entry `name` of `size` bytes (a pickled bytes object), last used `age_s` ago."""
    path = directory / "kind" / name[:2] / f"{name}.pkl"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(b"x" * size))
    t = time.time() - age_s
    os.utime(path, (t, t))
    return path


def test_the_cache_is_pruned_least_recently_used_first_and_a_hit_renews_an_entry(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    a, b, c = (_entry(root, n * 64, 1000, age) for n, age in (("a", 300), ("b", 200), ("c", 100)))
    monkeypatch.setenv(cache.MAX_GB_ENV, str((2 * a.stat().st_size) / 1e9))     # room for two
    with cache.use(root):
        assert cache.cached("kind", "a" * 64, lambda: "computed") == b"x" * 1000   # a hit renews a
    assert a.exists() and not b.exists() and c.exists()      # b is now the least recently used


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(0, 5000), min_size=0, max_size=12), limit=st.integers(0, 30_000))
def test_prune_leaves_at_most_the_limit_and_removes_oldest_first(tmp_path_factory, sizes, limit):
    root = tmp_path_factory.mktemp("cache")
    paths = [_entry(root, f"{i:02d}" + "0" * 62, size, age_s=1000 - i) for i, size in enumerate(sizes)]
    on_disk = [p.stat().st_size for p in paths]
    removed, freed = cache.prune(root, limit)
    left = [p for p in paths if p.exists()]
    kept = sum(p.stat().st_size for p in left)
    assert kept <= limit
    assert removed == len(paths) - len(left) and freed == sum(on_disk) - kept
    assert left == paths[len(paths) - len(left):]          # the survivors are the newest ones
    if removed:     # and no more than needed: the newest one removed would not have fitted
        assert kept + on_disk[removed - 1] > limit


@pytest.mark.parametrize("bad", ["-1", "lots", "nan"])
def test_a_bad_cache_limit_is_a_usage_error_before_the_run(tmp_path, monkeypatch, bad):
    monkeypatch.setenv(cache.MAX_GB_ENV, bad)
    ran = []
    with pytest.raises(UsageError, match=cache.MAX_GB_ENV):
        with cache.use(tmp_path / "cache"):
            ran.append(1)
    assert not ran
