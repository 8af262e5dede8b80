"""The Fig. 4 figure: a raster of sensor activity per trial and P(active) against lag.

Drawn with the object-oriented matplotlib API of :mod:`infomax_contingency.eval.plots`
(no display). Time on the x axis is the start of each window since the decision to
vocalize, in seconds (lag x ``dt``).
"""

from __future__ import annotations

from pathlib import Path

from infomax_contingency.eval.fig4 import Fig4Study
from infomax_contingency.eval.plots import _figure, _save


def fig4_figure(study: Fig4Study, raster: list[list[bool]], dt: float, path: str | Path) -> Path:
    """Draw the raster (top) and P(active) with 95 % bands and the periods (bottom)."""
    figure = _figure(7.0, 6.0)
    top, bottom = figure.subplots(2, 1, sharex=True)
    for row, bits in enumerate(raster):
        times = [lag * dt for lag, bit in enumerate(bits) if bit]
        top.scatter(times, [row] * len(times), s=4, color="black", marker="s")
    top.set_ylabel("trial (vocalization)")
    top.set_title(f"sensor activity after the robot's sound ({study.vocalizations} trials)")
    lags = [lag * dt for lag, rate in enumerate(study.by_lag) if rate.total]
    rates = [rate for rate in study.by_lag if rate.total]
    bottom.plot(lags, [r.value for r in rates], marker="o", label="P(active)")
    bottom.fill_between(lags, [r.interval[0] for r in rates], [r.interval[1] for r in rates],
                        alpha=0.3, label="95 % band")
    low, high = study.background.interval
    bottom.axhspan(low, high, color="grey", alpha=0.3, label="background (95 %)")
    for period, colour, name in ((study.self_period, "tab:red", "self"),
                                 (study.agent_period, "tab:green", "reply")):
        if period is not None:
            bottom.axvspan(period[0] * dt, (period[1] + 1) * dt, color=colour, alpha=0.15,
                           label=f"{name} period")
    bottom.set_xlabel("time since the decision to vocalize (s, window start)")
    bottom.set_ylabel("P(sensor active)")
    bottom.set_ylim(0, 1)
    bottom.legend(loc="upper right", fontsize="small")
    return _save(figure, path)
