"""``pokeworld swm-certify`` end to end at a tiny size: World collection under named variations, factor certificates,
a LeWM and its untrained twin through certify_model, the factor table and figure; bad input refused up front."""

import json

import pytest

from pokeworld.cli import main
from test_factors import planted_rollouts, write_swm_h5

TINY = ["--preset", "tiny", "--episodes", "24"]


def test_world_collected_corpus_runs_end_to_end_and_is_reused(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["swm-certify", "swm/PokeWorld-v0", *TINY, "--factors", "physics.mass", "physics.stiffness",
            "--out", str(out)]
    assert main(argv) == 0
    result = json.loads((out / "swm_certify.json").read_text())
    assert set(result["factors"]) == {"physics.mass", "physics.stiffness"}
    row = result["factors"]["physics.mass"]
    for key in ("certificate", "gru_oracle", "linear_floor", "ridge", "untrained", "gate_passed", "status"):
        assert key in row
    assert row["ridge"] is not None and row["untrained"] is not None  # the protocol probed the factor itself
    assert result["corpus"]["episodes"] == 24 and result["corpus"]["observations"] == ["proprio", "touch"]
    protocol = json.loads((out / "protocol" / "protocol.json").read_text())
    assert set(protocol["probes"]["ridge"]["all"]) == {"physics.mass", "physics.stiffness"}
    assert protocol["certificates"]["source"] == "given"
    md = (out / "swm_certify.md").read_text()
    assert "| factor | certificate (GRU oracle / linear floor) |" in md and "| physics.mass |" in md
    assert (out / "swm_certify.png").stat().st_size > 0
    assert set(result["cost_seconds"]) == {"collect_s", "certify_s", "train_s", "protocol_s", "total_s"}
    capsys.readouterr()
    assert main(argv) == 0  # the second run reuses the corpus and the trained LeWM
    printed = capsys.readouterr().out
    assert "reusing" in printed and "is trained" in printed


def test_a_labelled_dataset_certifies_its_planted_factor_and_not_the_noise(tmp_path):
    data = write_swm_h5(tmp_path / "planted.h5", planted_rollouts(160, 24))
    out = tmp_path / "planted"
    assert main(["swm-certify", "--data", data, "--preset", "tiny", "--out", str(out), "--split-fractions", "0.2",
                 "0.4", "0.4", "--certificate.window", "8", "--certificate.stride", "1", "--certificate.epochs",
                 "150", "--certificate.patience", "20", "--certificate.gru-hidden", "32",
                 "--certificate.max-windows", "6000"]) == 0
    result = json.loads((out / "swm_certify.json").read_text())
    assert result["factors"]["drag.damping"]["status"] == "claim"
    assert result["factors"]["noise.level"]["status"] == "no claim (gate failed)"
    assert "not varied" in result["dropped_factors"]["floor.color[0]"]
    assert "Dropped factors" in (out / "swm_certify.md").read_text()


@pytest.mark.parametrize("args, message", [
    (["swm/PokeWorld-v0"], "name the factors to vary"),
    (["swm/PokeWorld-v0", "--factors", "physics.nope"],
     "has no variation \\['physics.nope'\\]; its variations: .*physics.mass"),
    (["swm/NoSuchEnv-v0", "--factors", "a.b"], "unknown environment 'swm/NoSuchEnv-v0'"),
    (["--data", "corpus.csv"], "must be an swm .h5/.hdf5 file or .lance table"),
])
def test_bad_input_is_one_line_before_any_collection(tmp_path, capsys, args, message):
    import re

    out = tmp_path / "bad"
    assert main(["swm-certify", *args, *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(message, err[0]), err
    assert not (out / "corpus.h5").exists()
