"""Which experiment would separate two explanations the record cannot tell apart.

When the held-out evidence does not separate the chosen finding from another candidate
(`civic.diagnose.forward.ALT_DBIC`), the report names a test that would: where possible one of
the plant's own procedures (fill test, drain test at two valve openings, inventory after a
known fill), otherwise a step test that moves the two components apart.
"""
from __future__ import annotations


def _kind(name: str) -> str:
    return {"valve_characteristic": "valve", "dead_time": "dead_time", "flow_law": "flow_law",
            "sensor_characteristic": "sensor", "sensor_offset": "sensor", "sensor_saturation": "sensor",
            "pump_dead_zone": "pump", "pump_head": "pump", "coefficient": "coefficient",
            "leak": "leak", "overflow": "overflow"}.get(name, name)


def separating_experiment(a, b, model=None) -> str:
    """A short description of a test that separates mechanisms `a` and `b` (Mechanism objects)."""
    ka, kb = sorted((_kind(a.name), _kind(b.name)))
    comps = " and ".join(dict.fromkeys(str(c) for c in (a.component, b.component)))
    valve = next((m.component for m in (a, b) if m.name in ("valve_characteristic", "dead_time")
                  and str(m.component).startswith("V")), None)
    link = next((m.component for m in (a, b) if m.name in ("flow_law", "coefficient")), None)
    if {ka, kb} == {"flow_law", "valve"} or (ka == kb == "flow_law"):
        v = valve or link or comps
        return (f"a drain test at two {v} openings (e.g. 30 % and 100 %) from the same start level: "
                "a valve characteristic scales the flow at a given head, a flow law bends it with the head")
    if "sensor" in (ka, kb):
        s = a.component if _kind(a.name) == "sensor" else b.component
        return (f"a static calibration of {s}: fill its tank by known volumes with every valve and the "
                "pump shut and read the sensor at three or more levels (a sensor map shows without any "
                "flow; a flow law or coefficient does not)")
    if ka == kb == "leak" or (ka == "leak" and kb == "overflow") or (ka == "coefficient" and kb == "leak"):
        return ("an inventory: fill the circuit with a measured volume, run, drain everything into the "
                "reservoir and read it again (water leaving the plant shows; water moved between tanks "
                "does not), and a hold test with every valve and the pump shut (a leak drains a tank "
                "that should stay still)")
    if "pump" in (ka, kb):
        pump = next(m.component for m in (a, b) if _kind(m.name) == "pump")
        tank, shut = _delivery(model, pump)
        return (f"a pump step test{shut}: commands 2 %, 5 %, 10 %, 30 %, 60 % of the range for 20 s each "
                f"into {tank} (a dead zone shows as no rise at the small commands, a head effect as a rate "
                f"that falls with {tank}'s level, a gain as the same factor at every command)")
    if "closure" in (ka, kb):
        c = next(m for m in (a, b) if m.name == "closure")
        if "until" in c.fixed:
            return (f"the plant's own test procedures now (the drain test for the drain line, the fill test "
                    f"for the pump line) against the same tests recorded while {c.component} passed less "
                    "(or the operators' log of the manual valves): a closure that ended leaves today's "
                    "test normal, a standing property of the plant does not")
        return (f"the plant's own test procedures now (the drain test for the drain line, the fill test for "
                f"the pump line) against a run before {c.fixed['onset']:g} s: a closure since then shows in "
                "the test's class, a standing property of the plant does not change between them")
    if "overflow" in (ka, kb):
        return ("a fill test past the suspected rim with the tank below isolated (its valve shut): "
                "the level at which the rise stops, and where the water goes, name the overflow")
    if "dead_time" in (ka, kb):
        return f"step tests of {comps} one at a time, the other actuators held: the delay of the first response"
    return f"step tests that move {comps} one at a time while the other actuators are held"


def _delivery(model, pump: str) -> tuple[str, str]:
    """The tank `pump` fills and, where its outflow has a valve, the words to shut it (the
    four-tank plant's T1 and V1 without a model)."""
    if model is None:
        return "T1", " with V1 shut"
    tank = model.find("pump", pump).to
    valves = [lk.valve for lk in model.links if lk.from_ == tank and lk.valve]
    return tank, f" with {' and '.join(valves)} shut" if valves else ""
