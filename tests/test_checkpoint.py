"""Checkpoints are read without executing code: a planted payload in a run's ckpt.pt / final.pt / the flow sensor
is refused with an error naming the file, and what pokeworld itself writes still loads and resumes."""

import os
import random

import numpy as np
import pytest
import torch

from pokeworld import checkpoint
from pokeworld.cli import main as cli_main
from pokeworld.data import save
from pokeworld.models.flow import load_flow
from pokeworld.train import load_model, make_config, run, synthetic_dataset


class Payload:
    """Unpickling this calls os.system: a stand-in for any code a crafted checkpoint could run."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("ck")
    save(synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), root / "syn")
    return run(make_config("tiny", data=str(root / "syn"), out=str(root / "run"), steps=4, variant="VX_t"))


def _plant(path, marker):
    ck = torch.load(path, weights_only=True)
    ck["extra"] = Payload(marker)
    torch.save(ck, path)


def test_pokeworld_checkpoints_load_weights_only(finished_run):
    for name in ("ckpt.pt", "final.pt"):
        torch.load(finished_run / name, weights_only=True)  # raises if anything but tensors / containers


def test_rng_state_round_trips_through_a_weights_only_file(tmp_path):
    random.seed(3), np.random.seed(4), torch.manual_seed(5)
    checkpoint.save({"rng": checkpoint.rng_state()}, tmp_path / "c.pt")
    expect = (random.random(), np.random.rand(), torch.rand(1).item())
    random.seed(0), np.random.seed(0), torch.manual_seed(0)
    checkpoint.set_rng_state(checkpoint.load(tmp_path / "c.pt")["rng"])
    assert (random.random(), np.random.rand(), torch.rand(1).item()) == expect


def test_planted_payload_in_final_pt_is_refused_by_load_and_probe(finished_run, tmp_path, capsys):
    run_dir = tmp_path / "shared_run"
    import shutil

    shutil.copytree(finished_run, run_dir)
    marker = tmp_path / "pwned"
    _plant(run_dir / "final.pt", marker)
    with pytest.raises(checkpoint.CheckpointError, match="final.pt"):
        load_model(run_dir)
    assert cli_main(["probe", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert "final.pt" in err and "Traceback" not in err
    assert not marker.exists()


def test_planted_payload_in_ckpt_pt_is_refused_on_resume(finished_run, tmp_path):
    kw = dict(data=str(finished_run.parent / "syn"), out=str(tmp_path / "resume_me"), steps=6, variant="VX_t")
    run_dir = run(make_config("tiny", stop_at=2, **kw))
    marker = tmp_path / "pwned"
    _plant(run_dir / "ckpt.pt", marker)
    with pytest.raises(checkpoint.CheckpointError, match="ckpt.pt"):
        run(make_config("tiny", **kw))
    assert not marker.exists()


def test_planted_payload_in_the_flow_sensor_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    torch.save({"state": {}, "config": {}, "meta": Payload(marker)}, tmp_path / "flow.pt")
    with pytest.raises(checkpoint.CheckpointError, match="flow.pt"):
        load_flow(tmp_path / "flow.pt")
    assert not marker.exists()


def test_damaged_or_missing_checkpoints_get_a_clear_error(tmp_path):
    (tmp_path / "half.pt").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(checkpoint.CheckpointError, match="half.pt"):
        checkpoint.load(tmp_path / "half.pt")
    with pytest.raises(checkpoint.CheckpointError, match="does not exist"):
        checkpoint.load(tmp_path / "absent.pt")
