"""Epoch alignment: skewed streams, dropouts, duplicates, out-of-order stamps, missing samples (no middleware)."""

from __future__ import annotations

import numpy as np

from taiji2_estimator_pkg.epochs import EpochAssembler

STREAMS = ("star_tracker", "grs1", "grs2")
DT = 100_000_000


def test_a_stream_far_ahead_does_not_release_epochs_early():
    a = EpochAssembler(STREAMS, max_lag_s=200.0)
    released = []
    for k in range(1000):  # the star tracker runs 100 s of stamps ahead (executor batching, a busy CPU)
        released += a.add("star_tracker", k * DT, k)
    assert released == []
    for k in range(1000):
        released += a.add("grs1", k * DT, k)
        released += a.add("grs2", k * DT, k)
    assert [e.t_ns for e in released] == [k * DT for k in range(1000)]
    assert all(len(e.samples) == 3 for e in released) and a.refused == {}


def test_a_stream_silent_while_another_delivered_max_lag_stops_holding_epochs_back_and_late_samples_are_refused():
    a = EpochAssembler(STREAMS, max_lag_s=2.0)     # 20 messages at 10 Hz
    out = []
    for k in range(40):
        out += a.add("star_tracker", k * DT, k)
        if k == 28:                                 # the 19th star-tracker message since grs2's last
            assert [e.t_ns for e in out] == [k * DT for k in range(10)]
        out += a.add("grs1", k * DT, k)
        if k < 10:
            out += a.add("grs2", k * DT, k)
    # grs2 stopped after 0.9 s: from star tracker's 20th message since (k = 29) it no longer holds epochs back
    assert [e.t_ns for e in out] == [k * DT for k in range(40)]
    assert all("grs2" not in e.samples for e in out[10:])
    assert a.missing() == {"star_tracker": 0, "grs1": 0, "grs2": 30}
    assert a.add("grs2", 11 * DT, 11) == []
    assert a.refused == {"grs2": {"out_of_order_stamp": 1}}


class _Clock:
    """A clock the test moves by hand [s]."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def test_a_reader_starved_while_the_others_deliver_batch_after_batch_is_not_taken_for_stopped_before_its_silence():
    """A lost datagram of one topic, repaired later: the other readers deliver two take batches (128 messages)
    meanwhile. With min_silence_s its 64 late samples still go into their epochs; once it has also been silent
    that long on the clock it has stopped, and release_stopped frees the epochs without it."""
    clock = _Clock()
    a = EpochAssembler(STREAMS, max_lag_s=10.0, min_silence_s=2.0, clock=clock)  # 100 messages
    out = []
    for k in range(10):  # in step
        for s in STREAMS:
            out += a.add(s, k * DT, k)
    for k in range(10, 138):  # grs2's reader has nothing: 128 messages of the others, 0.5 s of the clock
        clock.now_s += 0.5 / 128
        out += a.add("star_tracker", k * DT, k)
        out += a.add("grs1", k * DT, k)
    assert [e.t_ns for e in out] == [k * DT for k in range(10)]
    for k in range(10, 74):  # grs2's repaired batch of 64
        out += a.add("grs2", k * DT, k)
    assert [e.t_ns for e in out] == [k * DT for k in range(74)]
    assert all(len(e.samples) == 3 for e in out) and a.refused == {}
    # then grs2 stops for good while the others go on: held while its silence is shorter than 2 s (however many
    # messages the others deliver meanwhile), released once it is not
    for k in range(138, 400):
        out += a.add("star_tracker", k * DT, k)
        out += a.add("grs1", k * DT, k)
    clock.now_s += 1.9
    assert len(out) == 74 and a.release_stopped() == []
    clock.now_s += 0.2
    later = a.release_stopped()
    assert [e.t_ns for e in later] == [k * DT for k in range(74, 400)]
    assert all("grs2" not in e.samples for e in later)
    # without min_silence_s the message count alone decided: the same starved reader lost its batch
    b = EpochAssembler(STREAMS, max_lag_s=10.0)
    for k in range(10):
        for s in STREAMS:
            b.add(s, k * DT, k)
    for k in range(10, 138):
        b.add("star_tracker", k * DT, k)
        b.add("grs1", k * DT, k)
    for k in range(10, 74):
        b.add("grs2", k * DT, k)
    assert b.refused == {"grs2": {"out_of_order_stamp": 64}}


def test_a_stream_silent_before_its_slot_is_known_holds_epochs_back_until_it_stopped():
    """A stream's first samples wait for its slot (SLOT_SAMPLES of them, or until it stopped)."""
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    out = []
    for k in range(40):
        out += a.add("star_tracker", k * DT, k)
        if k == 23:                                 # grs2 sent 5 samples, then stopped: not yet declared
            assert out == []
        out += a.add("grs1", k * DT, k)
        if k < 5:
            out += a.add("grs2", k * DT, k)
    assert [e.t_ns for e in out] == [k * DT for k in range(40)]
    assert [len(e.samples) for e in out[:6]] == [3, 3, 3, 3, 3, 2]


def test_a_stream_behind_in_a_backlog_is_waited_for_however_far_the_others_ran_in_stamps():
    """With a backlog, a stream that had a gap (grs2: 250 samples lost) covers more stamps per message
    taken than the others: taken in round-robin batches it runs 25 s ahead in stamps, yet the star
    tracker and GRS1 keep delivering between its messages, so no epoch goes without them."""
    a = EpochAssembler(STREAMS, max_lag_s=10.0)
    stamps = {"star_tracker": list(range(2000)), "grs1": list(range(2000)),
              "grs2": [k for k in range(2000) if not 1000 <= k < 1250]}
    out = []
    while any(stamps.values()):
        for s in STREAMS:                             # the executor: up to 64 messages per reader per round
            batch, stamps[s] = stamps[s][:64], stamps[s][64:]
            for k in batch:
                out += a.add(s, k * DT, k)
    assert [e.t_ns for e in out] == [k * DT for k in range(2000)]
    assert a.refused == {}
    assert a.missing() == {"star_tracker": 0, "grs1": 0, "grs2": 250}


def test_the_epochs_released_depend_on_the_stamps_only_not_on_when_they_arrive():
    """Streams interleaved in any order within a tick (a publisher starved of CPU mid-tick, readers
    served in any order) give the same epochs: there is no clock in the assembler, only stamps."""
    rng = np.random.default_rng(7)
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    released = []
    for k in range(300):
        order = list(STREAMS)
        rng.shuffle(order)
        for s in order:
            released += a.add(s, k * DT, k)
    assert [e.t_ns for e in released] == [k * DT for k in range(300)]
    assert all(len(e.samples) == 3 for e in released)
    assert a.missing() == {s: 0 for s in STREAMS} and a.refused == {}


def test_missing_samples_are_counted_on_the_grid_from_the_first_sample_received():
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    for k in list(range(340, 400)) + list(range(450, 500)):   # joined at 34 s; every stream loses 5 s
        for s in STREAMS:
            if not (s == "star_tracker" and k % 10 == 3):         # and the star tracker every 10th sample
                a.add(s, k * DT, k)
    a.flush()
    assert a.first_ns == 340 * DT
    assert a.grid_stamps() == 160
    assert a.missing() == {"star_tracker": 50 + 11, "grs1": 50, "grs2": 50}


def test_a_stream_never_heard_is_waited_for_until_another_delivered_max_lag():
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    out = []
    for k in range(19):
        out += a.add("star_tracker", k * DT, k)
        out += a.add("grs1", k * DT, k)
    assert out == []
    out += a.add("star_tracker", 19 * DT, 19)
    assert [e.t_ns for e in out] == [k * DT for k in range(19)]
    assert a.missing()["grs2"] == 19


def test_duplicate_and_out_of_order_stamps_are_refused_and_counted():
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    a.add("grs1", 5 * DT, 0)
    a.add("grs1", 5 * DT, 0)
    a.add("grs1", 4 * DT, 0)
    assert a.refused == {"grs1": {"duplicate_stamp": 1, "out_of_order_stamp": 1}}


def test_the_counts_survive_a_checkpoint():
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
    _feed(a, STREAMS, range(10))
    _feed(a, ("grs1", "grs2"), range(10, 40))
    b = EpochAssembler(STREAMS, max_lag_s=2.0)
    b.load_state_dict(a.state_dict())
    assert b.missing() == a.missing() and b.missing()["star_tracker"] > 0


def test_a_checkpoint_holds_the_pending_epochs_and_the_samples_waiting_for_their_slot(tmp_path):
    """A node killed right after a checkpoint resumes from it: every sample the assembler had accepted is in it,
    so the epochs after the restart are those of the uninterrupted run (before, pending epochs were left out and
    their samples, sent again by a rerun, refused as out of order: lost)."""
    from taiji2_estimator_pkg.checkpoint import load_checkpoint, save_checkpoint

    def fed(a):
        out = _feed(a, ("grs1", "grs2"), range(0, 12))
        out += _feed(a, ("star_tracker",), range(0, 5))         # 5 samples: its slot unknown, they wait
        return out + _feed(a, ("grs1",), range(12, 30))         # grs1 ahead: epochs 12.. pending

    def rest(a):
        return (_feed(a, ("star_tracker",), range(5, 40)) + _feed(a, ("grs2",), range(12, 40))
                + _feed(a, ("grs1",), range(30, 40)))

    whole = EpochAssembler(STREAMS, max_lag_s=20.0)
    assert fed(whole) == [] and len(whole._pending) == 30
    first = EpochAssembler(STREAMS, max_lag_s=20.0)
    fed(first)
    save_checkpoint(tmp_path / "c.json", {"assembler": first.state_dict()})
    resumed = EpochAssembler(STREAMS, max_lag_s=20.0)
    resumed.load_state_dict(load_checkpoint(tmp_path / "c.json")["assembler"])
    after, uninterrupted = rest(resumed), rest(whole)
    assert len(after) == 40
    assert [(e.t_ns, e.samples, e.stamps) for e in after] == [(e.t_ns, e.samples, e.stamps) for e in uninterrupted]
    assert resumed.refused == {} and resumed.missing() == whole.missing()


def _feed(a, streams, stamps_k):
    out = []
    for k in stamps_k:
        for s in streams:
            out += a.add(s, k * DT, k)
    return out


def test_a_restarted_source_marks_where_its_rerun_is_taken_up():
    """Every stream going back in time (a simulator running its seed again) marks the first epoch
    taken up from the rerun; one stream going back (a stale or flooding peer on one topic), a late
    sample within the step-back bound, or the stamps the rerun repeats, mark nothing."""
    a = EpochAssembler(STREAMS, max_lag_s=2.0)
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
