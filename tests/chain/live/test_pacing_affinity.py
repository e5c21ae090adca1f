"""The pacing thread stays on one CPU while it sends on kernel SocketCAN (vcan keeps order per CPU backlog)."""

from __future__ import annotations

import os
import threading

import pytest

from benchtwin.chain.live.session import _pin_to_one_cpu


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs a Linux machine with two CPUs or more")
def test_the_pacing_thread_is_pinned_to_one_cpu_and_given_back_its_cpus() -> None:
    seen: dict[str, object] = {}

    def pacer() -> None:
        before = os.sched_getaffinity(0)
        previous = _pin_to_one_cpu()
        seen["during"] = os.sched_getaffinity(0)
        assert previous is not None
        os.sched_setaffinity(0, previous)
        seen["after"], seen["before"] = os.sched_getaffinity(0), before

    t = threading.Thread(target=pacer)
    t.start()
    t.join()
    assert len(seen["during"]) == 1 and seen["during"] <= seen["before"]
    assert seen["after"] == seen["before"]
    assert len(os.sched_getaffinity(0)) >= 2  # only the pacing thread was pinned, not the process
