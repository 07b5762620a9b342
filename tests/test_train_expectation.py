"""A long run says early how long it will take (from its first timed steps) and how to stop and resume; a short
one says nothing."""

from pokeworld.train.loop import LoopSchedule, Progress


def test_a_run_of_hours_says_its_expected_time_and_how_to_resume(capsys):
    p = Progress(LoopSchedule(0, 20000, 20000, 100, 1000, 1), "paper")
    p.expect(4, 27.3, 3)  # 9.1 s/step: the paper preset on 2 CPU cores
    line = capsys.readouterr().out
    assert "19996 more steps at 9.10 s/step" in line and "50.5 h" in line and "same command resumes" in line


def test_a_short_run_says_nothing(capsys):
    p = Progress(LoopSchedule(0, 4000, 4000, 50, 500, 1), "cpu")
    p.expect(4, 0.75, 3)  # 0.25 s/step: 17 minutes
    p.expect(4, 0.0, 0)
    assert capsys.readouterr().out == ""


class _SlowTrainee:
    """A trainee whose steps take 5 ms and whose budget ends after 6 steps, in a schedule of a million steps."""

    def step(self, step):
        import time

        import torch

        time.sleep(0.005)
        return {"loss": torch.tensor(1.0)}

    def out_of_time(self, step):
        return step >= 6

    def lr(self):
        return 1e-3

    def write_rows(self, row, acc, n):
        return 1.0

    def save_checkpoint(self, step):
        pass


def test_the_training_loop_says_it_on_a_cpu_after_its_first_timed_steps(capsys):
    import torch

    from pokeworld.train.loop import run_loop

    sched = LoopSchedule(0, 1_000_000, 1_000_000, 100, 1000, 1)
    assert run_loop(_SlowTrainee(), sched, torch.device("cpu"), Progress(sched, "slow")) == 6
    out = capsys.readouterr().out
    assert "expected: 999996 more steps" in out and "h on this machine" in out
