"""The CLI: preset layering, positional arguments, clear errors instead of tracebacks."""

import pytest

from pokeworld.cli import COMMANDS, PRESET_COSTS, _flag_arity, main, split_args
from pokeworld.errors import ConfigError
from pokeworld.experiments import MapConfig


def test_positional_and_preset_are_parsed():
    ar = _flag_arity(MapConfig)
    assert split_args(["--preset", "tiny", "OUT"], "out", ar) == ("tiny", ["--out", "OUT"])
    assert split_args(["OUT", "--variants", "V", "VX_t"], "out", ar) == ("cpu", ["--out", "OUT", "--variants", "V", "VX_t"])
    assert split_args(["--no-mlp-probes", "OUT", "--train-steps", "5"], "out", ar)[1] == \
        ["--no-mlp-probes", "--out", "OUT", "--train-steps", "5"]
    assert split_args(["--train-steps", "5", "OUT"], "out", ar)[1] == ["--train-steps", "5", "--out", "OUT"]


def test_the_positional_and_its_flag_are_one_argument(capsys):
    ar = _flag_arity(MapConfig)
    assert split_args(["--out", "B"], "out", ar)[1] == ["--out", "B"]  # either way alone
    for argv in (["A", "--out", "B"], ["--out=B", "A"]):
        with pytest.raises(ConfigError, match=r"--out given twice, as the bare word 'A' and as --out 'B'"):
            split_args(argv, "out", ar)
    assert main(["forecast-dependence", "A", "--out", "B"]) == 2  # one line, before anything runs
    assert "give it once" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["forecast-dependence", "--help"])
    assert "The bare OUT of the usage line is this option" in " ".join(capsys.readouterr().out.split())


def test_nested_tuple_flags_keep_their_values():
    from pokeworld.sim.generate import GenerateConfig

    ar = _flag_arity(GenerateConfig)
    argv = ["--policy.mode-weights", "0.2", "0.65", "0.15", "--physics.force-max", "5", "OUT"]
    assert split_args(argv, "out", ar)[1] == argv[:-1] + ["--out", "OUT"]


def test_errors_are_one_line_not_tracebacks(capsys, tmp_path):
    assert main(["certify", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["train", "--preset", "tiny", "--variant", "VQ", "--data", str(tmp_path)]) == 2
    assert "unknown variant" in capsys.readouterr().err
    assert main(["generate", "--preset", "huge"]) == 2
    assert "unknown preset" in capsys.readouterr().err
    assert main(["frobnicate"]) == 2


def test_generate_via_cli_writes_a_store(tmp_path):
    out = tmp_path / "d"
    assert main(["generate", "--preset", "tiny", str(out), "--num-episodes", "6", "--batch-envs", "6"]) == 0
    assert (out / "manifest.json").exists()


@pytest.mark.parametrize("cmd", ["generate", "certify", "train", "probe", "map", "demo", "pairs", "plan"])
def test_every_command_has_help(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert "usage" in capsys.readouterr().out.lower()


def test_top_level_help_lists_commands_and_preset_costs(capsys):
    from pokeworld.train import PRESETS

    for argv in ([], ["--help"], ["-h"]):
        assert main(argv) == 0
        out = capsys.readouterr().out
        lines = out.splitlines()
        for name, cmd in COMMANDS.items():  # one line per command, with its help
            assert sum(line.split()[:1] == [name] and cmd.help in line for line in lines) == 1, name
        assert set(PRESET_COSTS) == set(PRESETS)
        for name in PRESETS:
            assert any(line.split()[:1] == [name] and PRESET_COSTS[name] in line for line in lines), name
        assert "H100" in out and "2 CPU cores" in out


def test_training_commands_help_quotes_the_preset_cost(capsys):
    for argv, cost in ((["train", "--help"], PRESET_COSTS["cpu"]),
                       (["map", "--preset", "paper", "--help"], PRESET_COSTS["paper"]),
                       (["demo", "--help"], COMMANDS["demo"].cost)):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 0
        out = " ".join(capsys.readouterr().out.split())
        assert " ".join(cost.split()) in out, argv
    from pokeworld.train import TrainConfig

    assert "cpu" in TrainConfig.__doc__ and "paper" in TrainConfig.__doc__
