"""A GPU device call sends the repository's tracked files, at most 64 MiB with what it carries (the wheels, the
folders to resume from): the tracked tree stays under 56 MiB, so released models (about 8.3 MB each) can never make
the next lease impossible."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 56 << 20


@pytest.mark.skipif(not (ROOT / ".git").exists() or shutil.which("git") is None, reason="not a git checkout")
def test_the_tracked_tree_leaves_room_for_a_device_call():
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    sizes = {n.decode(): (ROOT / n.decode()).stat().st_size for n in names if n and (ROOT / n.decode()).is_file()}
    total = sum(sizes.values())
    largest = sorted(sizes.items(), key=lambda kv: -kv[1])[:5]
    assert total < LIMIT, f"the tracked tree is {total / 2**20:.1f} MiB (largest: {largest})"
