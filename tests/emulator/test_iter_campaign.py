"""The plant test by test: iter_campaign's chunks put end to end are simulate_campaign's Trace bit for bit."""

from __future__ import annotations

import numpy as np

from benchtwin.config import load_campaign, load_vehicle
from benchtwin.emulator import iter_campaign, simulate_campaign
from benchtwin.trace import TRACE_CHANNELS


def test_chunks_end_to_end_equal_the_whole_campaign() -> None:
    vehicle, campaign = load_vehicle(), load_campaign("quick.toml")
    whole = simulate_campaign(vehicle, campaign)
    chunks = list(iter_campaign(vehicle, campaign))
    assert len(chunks) == len(campaign.tests) == len(whole.segments)
    np.testing.assert_array_equal(np.concatenate([c.time_s for c in chunks]), whole.time_s)
    for name in TRACE_CHANNELS:  # thermal lumps included: their state runs on across the chunks
        np.testing.assert_array_equal(np.concatenate([c[name] for c in chunks]), whole[name], err_msg=name)
    assert [s for c in chunks for s in c.segments] == whole.segments
    for c, seg in zip(chunks, whole.segments):  # each chunk covers its test
        assert c.time_s[0] >= seg.start_s - 1e-9 and c.time_s[-1] <= seg.end_s + 1e-9
    assert chunks[-1].meta == whole.meta  # the ledger to the campaign's end
    assert chunks[0].meta["energy_ledger_j"] != whole.meta["energy_ledger_j"]
