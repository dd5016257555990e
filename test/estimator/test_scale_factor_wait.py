"""ScaleFactorWait and ScaleFactorHistory: d of the data up to t with G of the data up to t, and the bounds."""

from __future__ import annotations

from types import SimpleNamespace

from taiji2_estimator_pkg.scale_factor_wait import ScaleFactorHistory, ScaleFactorWait

S = 1_000_000_000
PERIOD, MAX_LAG = S, 5 * S


def _epochs(first_s: float, last_s: float) -> list:
    return [SimpleNamespace(t_ns=round(k * S / 10)) for k in range(round(first_s * 10), round(last_s * 10) + 1)]


def _stamps(epochs: list) -> list[float]:
    return [e.t_ns / S for e in epochs]


def test_no_wait_before_any_scale_factors():
    wait = ScaleFactorWait()
    assert _stamps([r for e in _epochs(0.0, 0.3) for r in wait.add(e, PERIOD, MAX_LAG)]) == [0.0, 0.1, 0.2, 0.3]


def test_epochs_go_on_once_the_scale_factors_of_their_period_have_come():
    wait = ScaleFactorWait()
    wait.scale_factors_through(2 * S, PERIOD, MAX_LAG)
    out = [r for e in _epochs(2.0, 4.2) for r in wait.add(e, PERIOD, MAX_LAG)]
    assert _stamps(out) == _stamps(_epochs(2.0, 2.9))  # period 2 has its G; 3 and 4 wait
    assert _stamps(wait.scale_factors_through(3 * S, PERIOD, MAX_LAG)) == _stamps(_epochs(3.0, 3.9))
    # an older stamp (a restarted scale-factor estimator) releases nothing; the held wait for it to catch up
    assert wait.scale_factors_through(2_500_000_000, PERIOD, MAX_LAG) == [] and wait.through_ns == 2_500_000_000
    assert _stamps(wait.release_all()) == [4.0, 4.1, 4.2] and wait.released_early == 3
    assert wait.pending == type(wait.pending)()


def test_at_most_max_lag_of_data_waits():
    wait = ScaleFactorWait()
    wait.scale_factors_through(0, PERIOD, MAX_LAG)
    out = [r for e in _epochs(1.0, 7.0) for r in wait.add(e, PERIOD, MAX_LAG)]
    # the held span never exceeds 5 s of data: 1.0 .. 1.9 go on with the last G as 6.1 .. 7.0 arrive
    assert _stamps(out) == _stamps(_epochs(1.0, 1.9)) and wait.released_early == 10
    assert wait.pending[-1].t_ns - wait.pending[0].t_ns <= MAX_LAG


def test_history_gives_the_scale_factors_of_the_data_up_to_the_epoch():
    history = ScaleFactorHistory()
    assert history.through(5 * S) is None and history.newest() is None
    for k in (1, 2, 3):
        history.add(k * S, f"G{k}", f"P{k}")
    assert history.through(S // 2) is None  # none of data that old
    assert history.through(2 * S + 5)[1] == "G2"  # G3 (of data after the epoch) has come already: not used
    assert history.through(3 * S)[1] == "G3" and history.newest()[1] == "G3"
    assert history.through(10 * S)[1] == "G3"  # the newest is kept
    history.add(S, "G1'", "P1'")  # restarted: an older stamp starts the history again
    assert history.newest()[1] == "G1'" and history.through(3 * S)[1] == "G1'" and len(history.entries) == 1
