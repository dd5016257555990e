"""The one epoch rule (taiji2_estimator_pkg.epochs): phases, jitter, late start, gaps, duplicates, reordering,
and the bulk and streaming paths giving the same epochs for the same samples in stamp order (no middleware)."""

from __future__ import annotations

import heapq

import numpy as np
import pytest

from taiji2_estimator_pkg.epochs import EpochAssembler, grid_streams

P = 100_000_000  # 10 Hz [ns]
T0 = 1_700_000_000 * 10**9
N = 3000


def _streams(rng, st_phase_ms, jitter_ms=0.0, st_start=0, grs2_phase_ms=0.0):
    """Stamps of three streams on the GRS clock: the star tracker ``st_phase_ms`` after the GRS instants."""
    k = np.arange(N)

    def stamps(phase_ms, first=0):
        t = T0 + k[first:] * P + round(phase_ms * 1e6)
        return t + np.rint(rng.normal(0.0, jitter_ms * 1e6, t.size)).astype(np.int64) if jitter_ms else t

    return {"grs1": stamps(0.0), "grs2": stamps(grs2_phase_ms), "star_tracker": stamps(st_phase_ms, st_start)}


def _payload(t):
    return np.column_stack((t, np.ones(t.size, dtype=np.int64)))


@pytest.mark.parametrize("phase_ms", [0.0, 20.0, 40.0, 50.0, 70.0])
@pytest.mark.parametrize("jitter_ms", [0.0, 2.0])
def test_each_phase_and_a_few_ms_of_jitter_keep_every_sample_in_its_own_epoch(phase_ms, jitter_ms):
    rng = np.random.default_rng(int(phase_ms * 10 + jitter_ms))
    streams = _streams(rng, phase_ms, jitter_ms)
    g = grid_streams({s: (t, _payload(t)) for s, t in streams.items()}, 0.1)
    assert g.refused == {}
    # at 50 ms or more the star tracker's first sample is nearer the second GRS instant (its epoch 0 is
    # empty) and its last one makes an epoch after the GRS's last
    late = int(phase_ms >= 50)
    assert g.n == N + late and g.missing() == {"grs1": late, "grs2": late, "star_tracker": late}
    # the star tracker keeps its phase (wrapped into [-P/2, P/2)) and its stamps: nothing is resampled
    expected = (phase_ms + 50.0) % 100.0 - 50.0
    # bound: the slot is the median of 9 stamps (sigma ~ 1.25 * 2 ms / 3 each for the star tracker and the
    # origin's GRS stamp, about 1.4 ms together); 6 ms is 4 sigma
    assert abs(g.offset_s("star_tracker") * 1e3 - expected) <= (6.0 if jitter_ms else 1e-6)
    # the robust phase over all 3000 samples: within 1 ms of the truth plus the origin's own jitter (<= 8 ms)
    assert abs(g.phase_ns["star_tracker"] / 1e6 - g.phase_ns["grs1"] / 1e6 - expected) <= (1.0 if jitter_ms else 1e-6)
    first = g.index["star_tracker"][0]
    assert first == (1 if phase_ms >= 50 else 0)
    np.testing.assert_array_equal(g.stamps_ns["star_tracker"], np.sort(streams["star_tracker"]))
    np.testing.assert_array_equal(g.index["star_tracker"], np.arange(first, first + N))


def test_a_stream_starting_later_gaps_duplicates_and_reordering_are_counted_by_reason():
    rng = np.random.default_rng(3)
    streams = _streams(rng, 40.0, 2.0, st_start=500)
    st = streams["star_tracker"]
    gap = (st >= T0 + 1000 * P) & (st < T0 + 1100 * P)           # 100 samples lost
    st = st[~gap]
    duplicated = st[[10, 20, 30]]                                 # three repeated messages
    extra = st[[40, 50]] + 20_000_000                             # two second samples 20 ms later in an epoch
    off = st[[60]] + 30_000_000                                   # 30 ms from its slot: off the grid
    early = T0 - 3 * P + 40_000_000                               # before the GRS started
    stamps = np.concatenate((st, duplicated, extra, off, [early]))
    stamps = stamps[rng.permutation(stamps.size)]                 # delivered in any order
    streams["star_tracker"] = stamps
    g = grid_streams({s: (t, _payload(t)) for s, t in streams.items()}, 0.1)
    assert g.refused == {"star_tracker": {"duplicate_stamp": 3, "off_grid_stamp": 1, "before_start": 1,
                                          "duplicate_epoch": 2}}
    assert g.missing()["star_tracker"] == 500 + 100
    assert g.n == N and g.index["star_tracker"].size == N - 600
    # the sample kept in each epoch is its stream's own (the first by stamp), not a shifted copy
    kept = g.values["star_tracker"][:, 0]
    np.testing.assert_array_equal(kept, g.stamps_ns["star_tracker"])
    # within 15 ms of its phase (2 ms rms jitter of its own and of the origin's stamp): none of the copies
    # 20 or 30 ms later
    assert np.all(np.abs(kept - g.t_ns[g.index["star_tracker"]] - 40_000_000) <= 15_000_000)


def _merged(streams):
    """All samples of all streams in stamp order (ties: stream name), as the nodes get them in stamp order."""
    return list(heapq.merge(*[[(int(t), s) for t in ts] for s, ts in streams.items()]))


def _stream_epochs(streams, order, max_lag_s=5.0):
    a = EpochAssembler(("star_tracker", "grs1", "grs2"), max_lag_s=max_lag_s)
    epochs = []
    for t, s in order:
        epochs += a.add(s, t, (s, t))
    epochs += a.flush()
    return a, [(e.t_ns, dict(e.stamps)) for e in epochs if e.samples]


def _bulk_epochs(g):
    table: dict[int, dict[str, int]] = {}
    for s in g.index:
        for j, t in zip(g.index[s], g.stamps_ns[s], strict=True):
            table.setdefault(int(j), {})[s] = int(t)
    return [(int(g.t_ns[j]), table[j]) for j in sorted(table)]


@pytest.mark.parametrize("phase_ms", [0.0, 40.0, 50.0, 70.0])
def test_bulk_and_streaming_give_the_same_epochs_in_stamp_order(phase_ms):
    rng = np.random.default_rng(11 + int(phase_ms))
    streams = _streams(rng, phase_ms, 2.0, st_start=37, grs2_phase_ms=3.0)
    # gaps (up to 2 s, within max_lag_s), 2 % random loss on every stream, a few repeated messages
    for s in streams:
        keep = rng.random(streams[s].size) > 0.02
        keep[800 + 11 * len(s): 820 + 11 * len(s)] = False
        t = streams[s][keep]
        streams[s] = np.sort(np.concatenate((t, t[rng.choice(t.size, 3, replace=False)])))
    g = grid_streams({s: (t, t) for s, t in streams.items()}, 0.1)
    a, streamed = _stream_epochs(streams, _merged(streams))
    assert streamed == _bulk_epochs(g)
    assert a.refused == g.refused and a.missing() == g.missing()
    assert {s: a.offset_s(s) for s in streams} == {s: g.offset_s(s) for s in streams}


def test_late_messages_are_what_streaming_refuses_and_bulk_uses():
    """Delivered out of stamp order (a star-tracker message 3 s late), the assembler has released its epoch
    and refuses it as out of order; the bulk path sorts it in. Nothing else differs."""
    rng = np.random.default_rng(5)
    streams = _streams(rng, 40.0)
    order = _merged(streams)
    late = next(i for i, (t, s) in enumerate(order) if s == "star_tracker" and t > T0 + 500 * P)
    item = order.pop(late)
    order.insert(late + 3 * 30, item)  # 30 messages per second of three streams
    g = grid_streams({s: (t, t) for s, t in streams.items()}, 0.1)
    a, streamed = _stream_epochs(streams, order, max_lag_s=1.0)
    bulk = _bulk_epochs(g)
    assert a.refused == {"star_tracker": {"out_of_order_stamp": 1}} and g.refused == {}
    differs = [i for i, (x, y) in enumerate(zip(streamed, bulk, strict=True)) if x != y]
    assert len(differs) == 1 and "star_tracker" not in streamed[differs[0]][1]
