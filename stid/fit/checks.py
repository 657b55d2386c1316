"""Warnings where the data cannot identify a parameter. A number without its
limits is not a result: these say when to distrust one, and what to drive."""

from __future__ import annotations

import numpy as np


def add_identifiability_warnings(result, model, stretches) -> None:
    names = [e.name for e in model.effects]
    # the speeds actually driven (a track run's speed swings within one stretch): 10th and
    # 90th percentiles over all the data, so a brief excursion does not count as a second speed
    allv = np.concatenate([np.asarray(s.vx_series if getattr(s, "vx_series", None) is not None else [s.vx])
                           for s in stretches]) if stretches else np.array([])
    one_speed = len(allv) == 0 or np.percentile(allv, 90) / max(np.percentile(allv, 10), 1e-9) < 1.3
    if "actuator_lag" in names and "tyre_relaxation" in names and one_speed:
        result.warn("servo lag and tyre relaxation cannot be told apart from one speed: relaxation lag "
                    "scales with 1/speed, servo lag does not. Add the same random steer at a second speed")
    rel = result.stderr / np.maximum(np.abs(result.values), 1e-300)
    for n, r in zip(result.names, rel):
        if r > 0.3 and not model.param(n).zero == 0.0:
            result.warn(f"{n} is poorly identified (std. error {100 * r:.0f}% of its value): "
                        "more excitation or a longer run is needed")
    c = result.corr
    for i in range(len(result.names)):
        for j in range(i + 1, len(result.names)):
            # judged as printed ("strongly correlated: Cf-Cr +0.98" rounds to two places): 0.9798
            # printed as +0.98 without this warning read as a contradiction
            if round(abs(c[i, j]), 2) >= 0.98:
                # (each interval holds what the correlation leaves: a trial user read "not each one"
                # beside Cf and Cr at +-0.2%, both holding the truth, and did not know which to believe)
                result.warn(f"{result.names[i]} and {result.names[j]} are almost fully correlated "
                            f"({c[i, j]:+.3f}): the data determine a combination of them far better than each "
                            "one; each interval allows for that, but an error in one moves the other with it "
                            "(more speeds or steer frequencies separate them)")
