"""Where the held-out part starts (stages/held_out.py): after the latest onset for the effects with one, the
whole run's split for those present from the start when every onset lies a maneuver period before it.

Blind seed 13, set 17: a star-tracker noise beside a scale-factor drift from 5,800 s (3 h) was held out on the
last 1,670 s, after the drift's onset, where its 1-3 mHz excess has a handful of bins, and refused (z = -1.2).
"""

from __future__ import annotations

from taiji2_estimator_pkg.diagnosis.stages.held_out import held_out_splits

N = 108_000  # 3 h at 10 Hz
PERIOD = 3_000  # 300 s


def test_without_an_onset_both_splits_are_two_thirds_of_the_run():
    assert held_out_splits(N, [], 2.0 / 3.0, PERIOD) == (72_000, 72_000)


def test_an_effect_from_the_start_keeps_the_whole_runs_split_beside_an_early_onset():
    onset = 58_000  # 5,800 s
    split, plain = held_out_splits(N, [onset], 2.0 / 3.0, PERIOD)
    assert split == onset + round(2.0 / 3.0 * (N - onset)) == 91_333  # the drift: within its own span
    assert plain == 72_000  # the noise: 3,600 s held out instead of 1,670 s


def test_an_onset_near_or_past_the_whole_runs_split_holds_every_effect_out_after_it():
    for onset in (72_000 - PERIOD + 1, 72_000, 90_000):
        split, plain = held_out_splits(N, [onset, 10_000], 2.0 / 3.0, PERIOD)
        assert plain == split == onset + round(2.0 / 3.0 * (N - onset))
    # exactly a period before it: the whole run's split
    assert held_out_splits(N, [72_000 - PERIOD], 2.0 / 3.0, PERIOD)[1] == 72_000
