"""Epoch alignment: skewed streams, dropouts, duplicates, out-of-order stamps (no middleware)."""

from __future__ import annotations

from taiji2_estimator_pkg.epochs import EpochAssembler

STREAMS = ("star_tracker", "grs1", "grs2")
DT = 100_000_000


def test_a_stream_far_ahead_does_not_release_epochs_early():
    a = EpochAssembler(STREAMS, max_silence_s=2.0)
    released = []
    for k in range(1000):  # the star tracker runs 100 s of stamps ahead, within the same wall instant
        released += a.add("star_tracker", k * DT, k, now_s=0.0)
    assert released == []
    for k in range(1000):
        released += a.add("grs1", k * DT, k, now_s=0.1)
        released += a.add("grs2", k * DT, k, now_s=0.1)
    assert [e.t_ns for e in released] == [k * DT for k in range(1000)]
    assert all(len(e.samples) == 3 for e in released) and a.refused == {}


def test_a_silent_stream_stops_holding_epochs_back_and_late_samples_are_refused():
    a = EpochAssembler(STREAMS, max_silence_s=2.0)
    out = []
    for k in range(10):
        out += a.add("star_tracker", k * DT, k, now_s=0.0)
        out += a.add("grs1", k * DT, k, now_s=0.0)
        if k < 5:
            out += a.add("grs2", k * DT, k, now_s=0.0)
    assert [e.t_ns for e in out] == [k * DT for k in range(5)]
    assert a.expire(now_s=1.0) == []          # not silent for long enough yet
    late = a.expire(now_s=2.5)                 # grs2 silent for 2.5 s: its missing epochs go without it
    assert [e.t_ns for e in late] == [k * DT for k in range(5, 10)]
    assert all("grs2" not in e.samples for e in late)
    assert a.add("grs2", 6 * DT, 6, now_s=3.0) == []
    assert a.refused == {"grs2": {"out_of_order_stamp": 1}}


def test_a_stream_never_heard_is_waited_for_from_the_first_message():
    a = EpochAssembler(STREAMS, max_silence_s=2.0)
    assert a.add("star_tracker", 0, 0, now_s=10.0) == []
    assert a.add("grs1", 0, 0, now_s=10.5) == []
    assert [e.t_ns for e in a.expire(now_s=12.1)] == [0]


def test_duplicate_and_out_of_order_stamps_are_refused_and_counted():
    a = EpochAssembler(STREAMS, max_silence_s=2.0)
    a.add("grs1", 5 * DT, 0, now_s=0.0)
    a.add("grs1", 5 * DT, 0, now_s=0.0)
    a.add("grs1", 4 * DT, 0, now_s=0.0)
    assert a.refused == {"grs1": {"duplicate_stamp": 1, "out_of_order_stamp": 1}}


def _feed(a, streams, stamps_k, now_s=0.0):
    out = []
    for k in stamps_k:
        for s in streams:
            out += a.add(s, k * DT, k, now_s=now_s)
    return out


def test_a_restarted_source_marks_where_its_rerun_is_taken_up():
    """Every stream going back in time (a simulator running its seed again) marks the first epoch
    taken up from the rerun; one stream going back (a stale or flooding peer on one topic), a late
    sample within the step-back bound, or the stamps the rerun repeats, mark nothing."""
    a = EpochAssembler(STREAMS, max_silence_s=2.0)
    first = _feed(a, STREAMS, range(100))                 # run 1 up to 9.9 s
    first += _feed(a, ("grs1",), range(50))               # a stale peer on one topic
    first += _feed(a, STREAMS, range(100, 150))
    first += _feed(a, STREAMS, [145])                     # late by 0.4 s: refused, not a step back
    assert not any(e.after_restart for e in first)
    rerun = _feed(a, STREAMS, range(0, 200))              # the rerun from t = 0
    assert rerun[0].t_ns == 150 * DT                      # taken up once the rerun passed 14.9 s
    assert [e.t_ns for e in rerun if e.after_restart] == [150 * DT]
    # the rerun up to 14.8 s is out of order, its 14.9 s the stamp the stream is at
    assert a.refused["grs1"] == {"out_of_order_stamp": 50 + 1 + 149, "duplicate_stamp": 1}
