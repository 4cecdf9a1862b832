"""Verdicts on an attempt's metrics against a pack's benchmarks, for every procedure: a value as a person
reads it, a row per [metrics.NAME] (the value, the benchmark and what it rests on, whether it is met,
whether it is a critical error), the attempt's outcome and its line in words.

Plain functions on plain data, no GL and no ECS, belonging to no one procedure: a procedure's debrief
in the window and the records server's pages (every pack's) say the same thing from the same pack
data. A pack declares the benchmark, what it rests on (benchmark_basis: published, programme or
provisional) and its source, the critical value and the advice on each [metrics.NAME]
(docs/needle-procedures.md, "Benchmarks and critical errors").
"""

from __future__ import annotations

import math

from chainsim.systems.engine.haptics import DEVICE_MEASURES

#: what a metric's benchmark rests on ([metrics.NAME] benchmark_basis): the first is the default, a
#: benchmark no study or programme data stands behind (docs/validity.md)
BENCHMARK_BASES = ("provisional", "published", "programme")
PROVISIONAL = BENCHMARK_BASES[0]


def number(x: float | None, units: str = "") -> str:
    """A value as a person reads it: rounded to what matters (counts whole), with its units."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    x = float(x)
    if not units or units in ("images", "contacts"):
        text = f"{x:.0f}" if x == round(x) else f"{x:.1f}"
    elif abs(x) >= 100:
        text = f"{x:.0f}"
    elif units == "mGy":
        text = f"{x:.2f}"
    else:
        text = f"{x:.1f}"
    if text in ("-0", "-0.0", "-0.00"):
        text = text[1:]
    return f"{text} {units}".strip()


def verdicts(metrics_spec: dict, values: dict) -> list[dict]:
    """One row per [metrics.NAME] of the pack, in its order: the value, the benchmark and whether the
    value meets it (None: no benchmark), and whether it is a critical error.

    `values` maps metric names to numbers or None (an attempt's `metrics`). A metric with a critical
    value and no value at all (a needle that touched nothing has no needle error) is a critical error:
    there is nothing to show it was done. A metric only a force-feedback device measures has no row in an
    attempt made without one (DEVICE_MEASURES): the trainee did nothing it could judge."""
    out = []
    for name, spec in metrics_spec.items():
        v = values.get(name)
        v = None if v is None or not math.isfinite(float(v)) else float(v)
        if v is None and spec.get("measure") in DEVICE_MEASURES:
            continue
        lower = bool(spec.get("lower_is_better", True))
        bench = spec.get("benchmark")
        crit = spec.get("critical")
        passed = None
        if bench is not None:
            passed = v is not None and (v <= bench if lower else v >= bench)
        critical = crit is not None and (v is None or (v > crit if lower else v < crit))
        units = spec.get("units", "")
        out.append(
            {
                "name": name,
                "label": spec.get("label") or name,
                "units": units,
                "help": spec.get("help", ""),
                "value": v,
                "shown": number(v, units),
                "benchmark": bench,
                "threshold": "" if bench is None else ("\u2264 " if lower else "\u2265 ") + number(bench, units),
                "source": spec.get("benchmark_source", ""),
                # what the benchmark rests on; a benchmark without one is provisional (docs/validity.md)
                "basis": "" if bench is None else spec.get("benchmark_basis") or PROVISIONAL,
                "passed": passed,
                "critical": critical,
                "critical_note": spec.get("critical_note", "") if critical else "",
                "advice": spec.get("advice", "") if passed is False or critical else "",
            }
        )
    return out


def rested_on(rows: list[dict]) -> dict:
    """What each benchmark of a verdict rested on, as an attempt stores it (details.verdict.benchmarks):
    metric name -> its benchmark, basis and source when the attempt was judged."""
    return {
        r["name"]: {"benchmark": r["benchmark"], "basis": r["basis"], "source": r["source"]}
        for r in rows
        if r["benchmark"] is not None
    }


def basis_note(rows: list[dict]) -> str:
    """The line the debrief says under its verdicts when any benchmark is provisional ('' when none is)."""
    judged = [r for r in rows if r["basis"]]
    provisional = [r for r in judged if r["basis"] == PROVISIONAL]
    if not provisional:
        return ""
    if len(provisional) == len(judged):
        share = "every benchmark here rests"
    else:
        share = f"{len(provisional)} of {len(judged)} benchmarks here rest"
    return (
        f"Provisional: {share} on no study and no programme data (set by the pack's authors); "
        "a pass or fail against it is a guide, not evidence of proficiency"
    )


def outcome(rows: list[dict]) -> dict:
    """The attempt's verdict: passed only with no critical error and every benchmark met."""
    judged = [r for r in rows if r["passed"] is not None]
    met = sum(1 for r in judged if r["passed"])
    critical = [r["critical_note"] or r["label"] for r in rows if r["critical"]]
    return {
        "passed": not critical and met == len(judged),
        "met": met,
        "judged": len(judged),
        "critical": critical,
    }


def verdict_line(o: dict) -> str:
    if o["critical"]:
        return "FAILED: critical error - " + "; ".join(o["critical"])
    if o["passed"]:
        return f"PASSED: every benchmark met ({o['met']} of {o['judged']})"
    return f"FAILED: {o['met']} of {o['judged']} benchmarks met"
