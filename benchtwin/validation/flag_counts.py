"""The flagged and clipped samples of a Recording's channels, counted by blocks (validation.json's chain section)."""

from __future__ import annotations

import numpy as np

from benchtwin.recording import Flag, Recording

__all__ = ["FLAG_BLOCK", "flag_counts"]

#: samples of a channel whose flags are counted at a time
FLAG_BLOCK = 1 << 20


def flag_counts(rec: Recording) -> dict[str, dict[str, int]]:
    """Flagged and clipped samples per channel, a block of each at a time.

    Parameters
    ----------
    rec:
        The Recording; a lazy channel it had not loaded goes again after its count (one without a block reader is
        read whole).

    Returns
    -------
    dict
        ``{"flagged_samples": {name: n}, "clipped_samples": {name: n}}``, channels with none left out.
    """
    flagged, clipped = {}, {}
    kept = rec.loaded()
    for k, c in rec.channels.items():
        n_flag = n_clip = 0
        for a in range(0, len(c), FLAG_BLOCK):
            f = c.block(a, a + FLAG_BLOCK)[2]
            n_flag += int(np.count_nonzero(f))
            n_clip += int(np.count_nonzero(f & int(Flag.SATURATED)))
        if n_flag:
            flagged[k] = n_flag
        if n_clip:
            clipped[k] = n_clip
        if k not in kept:
            rec.drop([k])
    return {"flagged_samples": flagged, "clipped_samples": clipped}
