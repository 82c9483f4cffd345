"""The session's numbers in a clinician's words (presentation only: every number comes from the engine's
:meth:`~neckstrength.session.Session.snapshot`; nothing here estimates anything)
==========================================================================================================

- muscle groups by name, with a short legend (the thesis's group names, Tables B.2, B.4, B.6; data/thesis/);
- strength as a percentage of the expected value: the posterior mean ``f_c`` over the prior mean ``f_0`` (the
  model's baseline strength of the group times the session's prior scale ``a``, docs/session.md), not a normative
  population value;
- left/right asymmetry of paired groups (``X-R`` / ``X-L``, s3m24);
- each reading against the model's prediction (``predicted_N`` of the snapshot, a point prediction at the
  posterior-mean strengths): a reading more than :data:`RETEST_REL` away suggests a re-test (a mis-entry or a
  submaximal effort). The threshold is a heuristic of the app, not a calibrated test.
"""

from __future__ import annotations

RETEST_REL = 0.25      # |measured - predicted| / predicted above this: re-test suggested (heuristic)
RETEST_LABEL = ("re-test suggested when a reading differs from the model's prediction by more than "
                f"{RETEST_REL:.0%} (a heuristic threshold of the app, not calibrated; the prediction is a point value "
                "at the current estimate)")
REFERENCE_LABEL = ("% of expected: the estimate (posterior mean) over the model's baseline strength of the group "
                   "for this session's prior (the prior mean f_0 = a f'_base, docs/session.md); a model reference, "
                   "not a normative value for this person's age, sex or size")

# p2m7's group codes: T = trunk, C = cervical spine, S = skull; E = extension, F = flexion, B = both (thesis
# Figure 5.6b caption); the other models' names are Tables B.2 and B.4.
_LEGEND = {
    "TC-E": ("trunk-to-neck extensors (deep extensors)", "from the trunk to the cervical spine, behind it: multifidus, "
             "semispinalis and splenius cervicis, levator scapulae, posterior scalene"),
    "TC-F": ("trunk-to-neck flexors", "from the trunk to the cervical spine, in front: longus colli, anterior and "
             "middle scalenes"),
    "TS-B": ("sternocleidomastoid group", "from the sternum and clavicle to the skull; flexes and extends: "
             "sternocleidomastoid, cleido-occipital"),
    "TS-E": ("trunk-to-skull extensors", "from the trunk to the skull, behind: semispinalis capitis, splenius "
             "capitis, upper trapezius"),
    "TS-F": ("hyoid muscles", "from the trunk to the skull and jaw, in front: the hyoid muscles"),
    "CS-E": ("neck-to-skull extensor", "from the cervical spine to the skull, behind: splenius capitis (C6 part)"),
    "CS-F": ("neck-to-skull flexor", "from the cervical spine to the skull, in front: longus capitis"),
    "hyoids": ("hyoid muscles", "front of the neck, below the jaw"),
    "SCM": ("sternocleidomastoid", "the large oblique muscle on each side of the neck"),
    "scalenes": ("scalenes", "side of the neck, to the first ribs"),
    "LC": ("longus colli", "deep neck flexor in front of the spine"),
    "Lcol": ("longus colli", "deep neck flexor in front of the spine"),
    "Lcap": ("longus capitis", "deep flexor from the spine to the skull base"),
    "trap": ("upper trapezius", "top of the shoulder to the back of the head"),
    "spcap": ("splenius capitis group", "back of the neck, to the skull"),
    "semicap": ("semispinalis capitis", "large deep extensor to the back of the skull"),
    "levscap": ("levator scapulae group", "side and back of the neck, to the shoulder blade"),
    "mf": ("multifidus (deep extensors)", "the deep extensors along the spine; the group of the deficit question"),
    "multif": ("multifidus (deep extensors)", "the deep extensors along the spine; the group of the deficit question"),
    "spcerv": ("cervical erector group", "longissimus and iliocostalis cervicis"),
    "subocc": ("suboccipitals", "small deep muscles below the back of the skull"),
}
_SIDES = {"R": "right", "L": "left"}


def group_name(muscle: str) -> tuple[str, str, str]:
    """(base code, name in words, side or '') of a model muscle group such as ``TC-E`` or ``SCM-R``."""
    base, side = muscle, ""
    if muscle[-2:] in ("-R", "-L") and muscle[:-2] in _LEGEND:
        base, side = muscle[:-2], _SIDES[muscle[-1]]
    name = _LEGEND.get(base, (base, ""))[0]
    return base, name, side


def legend(muscles) -> list[dict]:
    """One entry per group code of ``muscles``: code, name, where (short description)."""
    seen = []
    for m in muscles:
        base, name, _ = group_name(m)
        if base not in [s["code"] for s in seen]:
            seen.append({"code": base, "name": name, "where": _LEGEND.get(base, ("", ""))[1]})
    return seen


def _pct(num, den):
    return None if num is None or den in (None, 0) else 100.0 * num / den


def clinician_view(snap: dict) -> dict:
    """The numbers of ``snap`` (:meth:`Session.snapshot`) as a clinician reads them: groups with % of expected,
    asymmetries, readings with re-test flags, the deficit answer with its label. Labels travel with the numbers."""
    rows = snap["estimate"]["rows"]
    groups = []
    for r in rows:
        base, name, side = group_name(r["muscle"])
        groups.append({"muscle": r["muscle"], "code": base, "name": name, "side": side,
                       "estimate_N": r["f_c"], "sd_N": r["sd_c"], "expected_N": r["f_0"],
                       "pct_expected": _pct(r["f_c"], r["f_0"]), "pct_sd": _pct(r["sd_c"], r["f_0"])})
    by = {g["muscle"]: g for g in groups}
    asym = []
    for g in groups:
        if g["side"] == "right" and f"{g['code']}-L" in by:
            left = by[f"{g['code']}-L"]
            mean = (g["estimate_N"] + left["estimate_N"]) / 2
            asym.append({"code": g["code"], "name": g["name"], "right_N": g["estimate_N"], "left_N": left["estimate_N"],
                         "right_minus_left_pct": _pct(g["estimate_N"] - left["estimate_N"], mean)})
    table, seen = [], set()              # one row per group code: both sides side by side where paired
    for g in groups:
        if g["code"] in seen and g["side"]:
            continue
        pair = [x for x in groups if x["code"] == g["code"] and x["side"]] if g["side"] else []
        if len(pair) == 2:
            seen.add(g["code"])
            a = next((x for x in asym if x["code"] == g["code"]), None)
            table.append({"code": g["code"], "name": g["name"], "cells": pair,
                          "right_minus_left_pct": a["right_minus_left_pct"] if a else None})
        else:
            table.append({"code": g["muscle"], "name": g["name"] + (f" ({g['side']})" if g["side"] else ""),
                          "cells": [g], "right_minus_left_pct": None})
    readings = []
    for m in snap["measurements"]:
        p = m["predicted_N"]
        rel = None if p in (None, 0) else (m["force_N"] - p) / p
        readings.append({"test": m["test"], "posture": m["posture"], "direction": m["direction"],
                         "force_N": m["force_N"], "predicted_N": p, "diff_pct": None if rel is None else 100 * rel,
                         "retest": rel is not None and abs(rel) > RETEST_REL,
                         "emg": ", ".join(f"{k} {v:g}" for k, v in (m.get("activations") or {}).items())})
    dec = snap.get("decision") or snap.get("deficit")
    answer = None
    if dec is not None:
        answer = {"kind": "decision" if snap.get("decision") else "deficit", "p_deficit": dec["p_deficit"],
                  "trend": dec["trend"], "decision": dec.get("decision"), "calibrated": bool(dec.get("calibrated")),
                  "label": dec["label"], "settings_label": dec.get("settings_label"),
                  "definition": dec.get("definition")}
    return {"groups": groups, "table": table, "paired": bool(asym), "legend": legend([r["muscle"] for r in rows]),
            "asymmetry": asym,
            "readings": readings, "retest_label": RETEST_LABEL, "reference_label": REFERENCE_LABEL,
            "uncertainty_label": snap["estimate"]["uncertainty_label"],
            "uncertainty_calibrated": bool(snap["estimate"].get("calibrated")),
            "predicted_label": snap["predicted_label"], "deficit": answer}
