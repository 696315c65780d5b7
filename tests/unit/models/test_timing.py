"""The timing pass protocol (:mod:`models.timing`) with a fake clock and fake kernels: the
interleaving order, the repeats and warm-up, synchronisation before every clock read, the
distributions and the per-round ratios to the reference."""

from __future__ import annotations

from typing import Any

import pytest

from models.timing import Kernel, distribution, fixed_threads, round_order, timing_pass


class FakeRuntime:
    """A clock and kernels on one event log: a kernel's work is "queued" by ``run`` and only
    finished (the clock advanced by its duration) by its ``sync``, as an asynchronous
    runtime would; a clock read while work is queued is logged as a violation."""

    def __init__(self) -> None:
        self.now = 0.0
        self.log: list[tuple[str, str]] = []
        self.queued: list[float] = []
        self.unsynced_reads = 0

    def clock(self) -> float:
        if self.queued:
            self.unsynced_reads += 1
        return self.now

    def kernel(self, name: str, seconds: list[float] | float, evals: int = 1000) -> Kernel:
        times = iter(seconds) if isinstance(seconds, list) else None

        def run() -> Any:
            self.log.append(("run", name))
            self.queued.append(next(times) if times is not None else float(seconds))  # type: ignore[arg-type]
            return name

        def sync(out: Any) -> None:
            self.log.append(("sync", name if out is None else f"{name}:out"))
            self.now += sum(self.queued)
            self.queued.clear()

        return Kernel(name, run, evals, "fake", sync)


def test01_round_robin_rotates_the_first_kernel() -> None:
    assert round_order(3, 0) == [0, 1, 2]
    assert round_order(3, 1) == [1, 2, 0]
    assert round_order(3, 4) == [1, 2, 0]
    rt = FakeRuntime()
    kernels = [rt.kernel(n, 1e-3) for n in ("reference", "a", "b")]
    rec = timing_pass(kernels, reference="reference", repeats=5, warmup=2, clock=rt.clock)
    # warm-up rounds 0, 1 are not recorded; recorded rounds 2..6 rotate on
    assert rec["order"] == [
        ["b", "reference", "a"],
        ["reference", "a", "b"],
        ["a", "b", "reference"],
        ["b", "reference", "a"],
        ["reference", "a", "b"],
    ]
    runs = [n for what, n in rt.log if what == "run"]
    assert len(runs) == 3 * 7  # every kernel once per round, warm-up included
    assert all(rec["costs"][k]["distribution"]["n"] == 5 for k in ("reference", "a", "b"))


def test02_every_clock_read_follows_a_sync() -> None:
    rt = FakeRuntime()
    kernels = [rt.kernel("reference", 2e-3), rt.kernel("a", 5e-3)]
    rec = timing_pass(kernels, reference="reference", repeats=5, clock=rt.clock)
    assert rt.unsynced_reads == 0
    # per call: sync (nothing pending) before the start read, run, sync of its output
    per_call = [rt.log[i : i + 3] for i in range(0, len(rt.log), 3)]
    for call in per_call:
        name = call[1][1]
        assert call == [("sync", name), ("run", name), ("sync", f"{name}:out")]
    # without the sync the async work would be charged to nobody: the times are the work's
    assert rec["costs"]["a"]["ns_per_eval"] == pytest.approx(5e-3 / 1000 * 1e9, rel=1e-9)


def test03_an_unsynchronised_kernel_would_be_caught() -> None:
    # The fake is a real oracle: a kernel whose sync does nothing leaves work queued at the
    # stop read, and the fake counts it.
    rt = FakeRuntime()
    lazy = Kernel("lazy", lambda: rt.queued.append(1e-3), 10, "fake")
    timing_pass([lazy], repeats=5, clock=rt.clock)
    assert rt.unsynced_reads > 0


def test04_distribution_and_relative_to_the_reference() -> None:
    rt = FakeRuntime()
    # the reference and "a" slow down together in round 3 (load): the ratio holds
    ref_s = [9.0, 1.0, 1.0, 1.0, 3.0, 1.0]  # first entry: the warm-up round
    a_s = [9.0, 2.0, 2.0, 2.0, 6.0, 2.0]
    kernels = [rt.kernel("reference", ref_s, evals=100), rt.kernel("a", a_s, evals=50)]
    rec = timing_pass(kernels, reference="reference", repeats=5, warmup=1, clock=rt.clock)
    a = rec["costs"]["a"]
    ns = [v / 50 * 1e9 for v in a_s[1:]]
    assert a["distribution"]["median"] == pytest.approx(sorted(ns)[2])
    assert a["distribution"]["min"] == pytest.approx(min(ns))
    assert a["distribution"]["max"] == pytest.approx(max(ns))
    # per round: (2 s / 50) / (1 s / 100) = 4, also in the slow round (6/50)/(3/100) = 4
    rel = a["relative"]
    assert rel["median"] == pytest.approx(4.0) and rel["max"] == pytest.approx(4.0)
    assert rel["iqr"] == pytest.approx(0.0, abs=1e-12) and rel["n"] == 5
    assert rec["costs"]["reference"]["relative"]["median"] == pytest.approx(1.0)
    assert rec["costs"]["a"]["macs_per_eval"] is None and "bytes_per_eval" in a
    m = rec["machine"]
    assert {"processor", "cores", "threads", "load_before", "load_after", "runtimes"} <= set(m)


def test05_distribution_quartiles() -> None:
    d = distribution([5.0, 1.0, 3.0, 2.0, 4.0])
    assert (d["median"], d["min"], d["max"], d["n"]) == (3.0, 1.0, 5.0, 5)
    assert (d["q1"], d["q3"], d["iqr"]) == (2.0, 4.0, 2.0)
    one = distribution([7.0])
    assert one["iqr"] == 0.0 and one["median"] == 7.0
    with pytest.raises(ValueError, match="no values"):
        distribution([])


def test06_bad_settings() -> None:
    rt = FakeRuntime()
    k = rt.kernel("a", 1e-3)
    with pytest.raises(ValueError, match="at least 5"):
        timing_pass([k], repeats=4, clock=rt.clock)
    with pytest.raises(ValueError, match="not one of the kernels"):
        timing_pass([k], reference="reference", clock=rt.clock)
    with pytest.raises(ValueError, match="repeat"):
        timing_pass([k, rt.kernel("a", 1e-3)], clock=rt.clock)


def test07_threads_fixed_and_restored() -> None:
    import drjit as dr
    import torch

    before = (dr.thread_count(), torch.get_num_threads())
    with fixed_threads(1):
        assert (dr.thread_count(), torch.get_num_threads()) == (1, 1)
    assert (dr.thread_count(), torch.get_num_threads()) == before


def test08_samples_sized_to_a_minimum_time() -> None:
    # 1 ms calls and a 10 ms minimum: after the warm-up each sample is 10 calls, each
    # synchronised, and the cost is still per evaluation
    rt = FakeRuntime()
    kernels = [rt.kernel("reference", 1e-3, evals=10), rt.kernel("long", 30e-3, evals=10)]
    rec = timing_pass(kernels, reference="reference", repeats=5, warmup=1, min_sample_s=10e-3,
                      clock=rt.clock)  # fmt: skip
    assert rec["costs"]["reference"]["calls"] == 10 and rec["costs"]["long"]["calls"] == 1
    runs = [n for what, n in rt.log if what == "run"]
    assert runs.count("reference") == 1 + 5 * 10 and runs.count("long") == 1 + 5
    assert rec["costs"]["reference"]["ns_per_eval"] == pytest.approx(1e-3 / 10 * 1e9)
    assert rec["costs"]["long"]["relative"]["median"] == pytest.approx(30.0)
    assert rt.unsynced_reads == 0
