"""``pokeworld swm-certify`` end to end at a tiny size: World collection under named variations, factor certificates,
a LeWM and its untrained twin through certify_model, the factor table and figure; bad input refused up front."""

import json

import numpy as np

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
    for key in ("certificate", "gru_oracle", "linear_floor", "local_dynamics", "ridge", "untrained", "gate_passed",
                "status"):
        assert key in row
    assert row["ridge"] is not None and row["untrained"] is not None  # the protocol probed the factor itself
    assert result["corpus"]["episodes"] == 24 and result["corpus"]["observations"] == ["proprio", "touch"]
    protocol = json.loads((out / "protocol" / "protocol.json").read_text())
    assert set(protocol["probes"]["ridge"]["all"]) == {"physics.mass", "physics.stiffness"}
    assert protocol["certificates"]["source"] == "given"
    md = (out / "swm_certify.md").read_text()
    assert "| factor | certificate (GRU oracle / linear floor / local dynamics) |" in md and "| physics.mass |" in md
    assert (out / "swm_certify.png").stat().st_size > 0
    assert set(result["factor_effects"]) == {"physics.mass", "physics.stiffness"}
    assert all("inert" in e and "effect" in e for e in result["factor_effects"].values())
    assert set(result["cost_seconds"]) == {"collect_s", "certify_s", "train_s", "protocol_s", "xjepa_s",
                                           "total_s"}
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


def test_the_variant_factorial_trains_probes_and_reports_every_variant(tmp_path, capsys):
    eps = planted_rollouts(48, 20)
    eps["pixels"] = eps["pixels"].repeat(2, 2).repeat(2, 3)  # 16 px: the smallest frame X-JEPA reads
    data = write_swm_h5(tmp_path / "planted16.h5", eps)
    out = tmp_path / "factorial"
    argv = ["swm-certify", "--data", data, "--preset", "tiny", "--out", str(out), "--variants", "V", "VF", "VX",
            "VFX", "--xjepa-seeds", "0", "1"]
    assert main(argv) == 0
    result = json.loads((out / "swm_certify.json").read_text())
    x = result["xjepa"]
    assert set(x["variants"]) == {"V", "VF", "VX", "VFX"} and x["seeds"] == [0, 1]
    for v, role in (("V", "absent"), ("VF", "input only"), ("VX", "target only"), ("VFX", "input and target")):
        assert x["state_role"][v] == role and set(x["variants"][v]) == {"0", "1"}
        config = json.loads((out / "xjepa" / "runs" / f"{v}-s1" / "config.json").read_text())
        assert config["variant"] == v and config["seed"] == 1 and config["window"] <= 21
    row = x["summary"]["drag.damping"]
    assert set(row["variants"]) == {"V", "VF", "VX", "VFX"}
    assert set(row["effects_ridge"]) == {"target_without_input", "target_with_input", "input_without_target"}
    cell = row["variants"]["VX"]
    assert cell["ridge"] == pytest.approx(np.mean([s["ridge"] for s in cell["per_seed"].values()]))
    md = (out / "swm_certify.md").read_text()
    assert "## Targets, not inputs?" in md and "VX (target only)" in md and "| drag.damping |" in md
    assert (out / "swm_certify_variants.png").stat().st_size > 0
    capsys.readouterr()
    assert main(argv) == 0  # trained variants are reused, not retrained
    assert "training" not in capsys.readouterr().out.lower().replace("x-jepa", "")


def test_a_variant_the_factorial_does_not_define_is_one_line(tmp_path, capsys):
    assert main(["swm-certify", "--data", "x.h5", *TINY, "--variants", "V", "VX_t", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--variants takes distinct names from ['V', 'VF', 'VX', 'VFX']" in err[0], err


def test_the_held_policy_collects_actions_held_for_several_steps(tmp_path):
    import h5py

    from pokeworld.swm.certify_env import collect, make_config

    cfg = make_config("tiny", env="swm/PokeWorld-v0", factors=("physics.mass",), episodes=4, policy="held",
                      hold=(3, 5), out=str(tmp_path))
    with h5py.File(collect(cfg, tmp_path / "corpus.h5"), "r") as f:
        actions, lengths = f["action"][()], f["ep_len"][()]
    first = actions[: lengths[0] - 1]  # one episode's transitions (the last row holds no transition)
    changes = np.flatnonzero(np.any(first[1:] != first[:-1], axis=-1)) + 1
    runs = np.diff(changes)
    assert len(changes) >= 2 and runs.min() >= 3 and runs.max() <= 5, changes


def test_the_factor_effect_check_on_swm_pokeworld():
    """A goal's radius changes no dynamics (inert); a default-config range of one value is unmeasured, not inert."""
    from pokeworld.swm.certify_env import variation_names
    from pokeworld.swm.factor_effect import factor_effects

    variation_names("swm/PokeWorld-v0")  # registers the environment
    got = factor_effects("swm/PokeWorld-v0", ("goal.radius", "physics.gain"), steps=8, seeds=(0,))
    assert got["goal.radius"]["inert"] is True and got["goal.radius"]["effect"] == 0
    assert got["physics.gain"]["inert"] is None and "single value" in got["physics.gain"]["unmeasured"]


def test_two_workers_collect_shares_merged_in_order(tmp_path):
    """--workers 2: two processes, distinct reset seeds (so distinct episodes), one merged corpus, no parts left."""
    import h5py

    from pokeworld.swm.certify_env import collect, make_config
    from pokeworld.swm.parallel_collect import shares

    assert shares(7, 2) == [4, 3] and shares(1, 4) == [1]
    cfg = make_config("tiny", env="swm/PokeWorld-v0", factors=("physics.mass",), episodes=5, steps=12, workers=2,
                      out=str(tmp_path))
    path = collect(cfg, tmp_path / "corpus.h5")
    with h5py.File(path, "r") as f:
        lengths, offsets = f["ep_len"][()], f["ep_offset"][()]
        mass = f["variation.physics.mass"][()][offsets].ravel()
        proprio = f["proprio"][()]
    assert len(lengths) == 5 and (offsets == np.concatenate([[0], np.cumsum(lengths)[:-1]])).all()
    assert len(np.unique(mass)) == 5  # every episode its own draw: the workers' seeds do not overlap
    assert not np.array_equal(proprio[offsets[0]], proprio[offsets[3]])
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != ".pokeworld-owned") == ["corpus.h5"]
