"""Property-based damage to run folders (issue #40): truncated or retyped config.json / metrics.jsonl / checkpoints,
links, FIFOs and folders under a run's file names, and model kwargs declaring huge or mismatched models. Every
reader (``probe``'s, ``load_model``) and a resumed ``train`` either succeeds or ends in one ``ConfigError`` /
``DataError`` line: never a hang, another exception, a write through a link, or a large allocation.

Cheap by construction: one tiny run is trained per module; an example copies its few small files into a fresh
folder and damages one. Deterministic (``derandomize``) for CI; about 20 s in all.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import shutil
import signal
import tempfile
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from pokeworld import rundir
from pokeworld.data import save
from pokeworld.errors import PokeworldError
from pokeworld.models.xjepa import MODEL_KWARGS
from pokeworld.train import make_config, run, synthetic_dataset

FILES = ("config.json", "metrics.jsonl", "final.pt", "ckpt.pt", "DONE")
SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                         HealthCheck.too_slow])
RUN_KW = dict(steps=10, variant="VX_t")
MAX_GROWTH_KB = 512 * 1024  # peak RSS an example may add: far below any model its kwargs could declare


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[str, Path]:
    root = tmp_path_factory.mktemp("fuzzrun")
    save(synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), root / "syn")
    return str(root / "syn"), run(make_config("tiny", data=str(root / "syn"), out=str(root / "run"), **RUN_KW))


@contextlib.contextmanager
def time_limit(seconds: float):
    """TimeoutError in the main thread after ``seconds`` (a blocking open of a FIFO included)."""
    def expire(signum, frame):
        raise TimeoutError(f"hung for {seconds} s")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


json_values = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner,
                                                                                       max_size=3), max_leaves=8)
kwarg_values = (st.integers(-2**40, 2**40) | st.integers(0, 70000) | st.floats() | st.booleans() | st.text(max_size=6)
                | st.lists(st.integers(-5, 70000), max_size=6) | st.none())
damages = st.one_of(
    st.tuples(st.just("truncate"), st.sampled_from(FILES), st.floats(0, 1)),
    st.tuples(st.just("retype"), st.sampled_from(("config.json", "metrics.jsonl")), json_values),
    st.tuples(st.just("line"), st.just("metrics.jsonl"), json_values),
    st.tuples(st.just("link"), st.sampled_from(FILES + (".lock",)), st.sampled_from(("victim", "dangling", "dir"))),
    st.tuples(st.just("special"), st.sampled_from(FILES + (".lock",)), st.sampled_from(("fifo", "dir"))),
    st.tuples(st.just("kwargs"), st.sampled_from(("final.pt", "ckpt.pt")),
              st.dictionaries(st.sampled_from(sorted(MODEL_KWARGS) + ["evil"]), kwarg_values, min_size=1,
                              max_size=3)),
    st.tuples(st.just("flip"), st.sampled_from(FILES), st.integers(0, 10**6)),
)


def damage(run_dir: Path, victim: Path, how: tuple) -> None:
    kind, name, arg = how
    path = run_dir / name
    if kind == "truncate" and path.exists():
        raw = path.read_bytes()
        path.write_bytes(raw[: int(len(raw) * arg)])
    elif kind == "retype":
        path.write_text(json.dumps(arg) + ("\n" if name == "metrics.jsonl" else ""))
    elif kind == "line":
        with open(path, "a") as fh:
            fh.write(json.dumps(arg) + "\n")
    elif kind in ("link", "special"):
        path.unlink(missing_ok=True)
        if arg == "fifo":
            os.mkfifo(path)
        elif arg == "dir":
            path.mkdir() if kind == "special" else path.symlink_to(victim.parent)
        else:
            path.symlink_to(victim if arg == "victim" else run_dir / "nowhere")
    elif kind == "kwargs" and path.exists():
        ck = torch.load(path, weights_only=True)
        ck["model_kwargs"] = {**ck["model_kwargs"], **arg}
        torch.save(ck, path)
    elif kind == "flip" and path.exists():
        raw = bytearray(path.read_bytes())
        if raw:
            raw[arg % len(raw)] ^= 0xFF
            path.write_bytes(bytes(raw))


@contextlib.contextmanager
def damaged_copy(src: Path, how: tuple, drop: tuple[str, ...] = ()):
    """A copy of the run ``src`` with ``how`` applied (and ``drop`` removed), and a victim file outside it."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        victim = tmp / "precious" / "victim.txt"
        victim.parent.mkdir()
        victim.write_text("precious\n")
        run_dir = Path(shutil.copytree(src, tmp / "run", ignore=shutil.ignore_patterns("tb", ".lock", *drop)))
        cfg = json.loads((run_dir / "config.json").read_text())
        (run_dir / "config.json").write_text(json.dumps({**cfg, "out": str(run_dir)}))  # the copy is this run
        damage(run_dir, victim, how)
        yield run_dir
        assert victim.read_text() == "precious\n" and sorted(os.listdir(victim.parent)) == ["victim.txt"]


def ends_well(fn, *args) -> None:
    """``fn(*args)`` succeeds or raises a one-line pokeworld error, within 10 s and without a large allocation."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with time_limit(10):
            fn(*args)
        event(f"{fn.__name__}: ok")
    except PokeworldError as e:
        assert "\n" not in str(e) and str(e), repr(e)
        event(f"{fn.__name__}: {type(e).__name__}")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < MAX_GROWTH_KB


@settings(max_examples=120, **SETTINGS)
@given(how=damages)
def test_reading_a_damaged_run_ends_in_a_load_or_one_line(trained, how):
    with damaged_copy(trained[1], how) as run_dir:
        for reader in (rundir.finished_run_config, rundir.read_metrics, rundir.last_logged_step, rundir.load_model):
            ends_well(reader, run_dir)


@settings(max_examples=25, **SETTINGS)
@given(how=damages)
def test_resuming_a_damaged_run_ends_in_a_finished_run_or_one_line(trained, how):
    """ckpt.pt holds the last step, so a resume that gets past every check loads it and finishes without training."""
    data, src = trained
    with damaged_copy(src, how, drop=("DONE", "final.pt")) as run_dir:
        ends_well(run, make_config("tiny", data=data, out=str(run_dir), **RUN_KW))
