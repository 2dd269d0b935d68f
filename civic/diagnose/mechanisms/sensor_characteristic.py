"""Sensor characteristic: a non-linear level -> signal map, y = gain*q**exponent + offset.

Beyond `sensor_offset` (a shift of a linear map): a level sensor (pressure cell,
float, ultrasound) whose reading bends with the level. Offset, gain (a factor on the
model's) and exponent are fitted; or, as the quadratic variant, gain, offset and a
curvature about the readings' middle, y = gain*q + curvature*(q - pivot)**2 + offset.
"""
from __future__ import annotations

import copy as _copy

import numpy as np

from ..compare import INVENTORY_BAND, INVENTORY_SPREAD
from .base import Mechanism, below_rim, drives_no_flow


STILL_SIGMAS = 10.0   # readings within this many noise sigmas (1st-99th percentile): a still tank


class SensorCharacteristic(Mechanism):
    name = "sensor_characteristic"
    # the model's offset and gain; the readings' range and middle; where a tank seen at its rim reads
    hidden = ("base", "base_gain", "range", "q_mid", "anchor")

    def edit(self, model, p):
        self.edit_sensor(model.find("sensor", self.component), p)

    def edit_sensor(self, s, p):
        base_gain = float(self.fixed.get("base_gain", 1.0))
        s.offset = float(self.fixed.get("base", 0.0)) + float(p["offset"])
        if "curvature" in p:
            s.exponent, s.pivot = 1.0, float(self.fixed.get("q_mid", 0.0))
            s.curvature = base_gain * float(p["curvature"])
            s.gain = base_gain * float(p["gain"])
            return
        s.exponent = float(p["exponent"])
        s.gain = base_gain * (float(p["gain"]) if "gain" in p else self._tied_gain(p))

    def _tied_gain(self, p) -> float:
        """The gain factor of the tied maps. Bend and offset free: the map equals the model's at
        the middle of the readings (q_mid), so the curve cannot slide along the gain/exponent/
        offset valley of a narrow range (which extrapolates wildly). The bend alone (a tank seen
        at its rim): the map passes through (rim, the plateau's reading) with the model's zero."""
        n = float(p["exponent"])
        if "offset" not in self.params and self.fixed.get("anchor"):
            q_a, y_a = self.fixed["anchor"]
            top = y_a - float(self.fixed.get("base", 0.0)) - float(p.get("offset", 0.0))
            return max(top, 1e-9) / (float(self.fixed.get("base_gain", 1.0)) * max(q_a, 1e-9) ** n)
        q_mid = max(float(self.fixed.get("q_mid", 1.0)), 1e-9)
        return q_mid ** (1.0 - n)

    @classmethod
    def candidates(cls, model, loc):
        out = []
        for s in model.sensors:
            if s.name not in loc.signals_present or s.tank not in loc.tanks or s.exponent != 1.0 or s.curvature:
                continue        # a map already bent (a model improved before) is not bent again
            span = max(loc.signal_span.get(s.name, 1.0), 1e-6)
            rng = getattr(loc, "signal_range", {}).get(s.name)
            if rng is not None and rng[1] - rng[0] < STILL_SIGMAS * max(s.noise_sigma, s.resolution):
                # a reading that never leaves its noise band (an idle tank in a test) shows no map:
                # a bent map there only rescales the noise of its balance (on the 18 s drain tests
                # a still L1 got exponent 2 at its bound: a false finding on a normal run)
                continue
            fixed = {"base": s.offset, "base_gain": s.gain, "range": rng,
                     "q_mid": float(s.invert(0.5 * (rng[0] + rng[1]))) if rng else 1.0,
                     "anchor": _rim_anchor(model, loc, s)}
            out.append(cls(s.name, {"exponent": 1.02, "offset": 0.0, "gain": 1.0},
                           {"exponent": (0.5, 2.0), "offset": (-0.25 * span, 0.25 * span), "gain": (0.2, 3.0)},
                           fixed))
            if fixed["anchor"]:
                # a tank held at its rim pins the map's top: the bend alone, through the rim and
                # the model's zero. (Tied at the middle instead, the bend and the offset slid along
                # a flat valley on part of the record and missed its lowest levels: a bent L1 with
                # T1 at its rim was named an overflow)
                out.append(cls(s.name, {"exponent": 1.02}, {"exponent": (0.5, 2.0)}, dict(fixed)))
        return out

    @property
    def label(self) -> str:
        how = ", quadratic" if "curvature" in self.params else "" if "offset" in self.params else \
            ", through zero" if "gain" in self.params else ", bend through the rim"
        return f"{self.name}({self.component}{how})"

    def tied(self) -> "SensorCharacteristic":
        """The two-parameter variant (exponent, offset; gain tied at the readings' middle)."""
        return self._without("gain")

    def through_zero(self) -> "SensorCharacteristic":
        """The two-parameter variant through the model's zero (exponent, gain; an empty tank reads
        what the model says): a sensor calibrated far from the levels it is seen at. The map tied at
        the middle of those levels cannot hold it: a reservoir sensor bent by 0.85, exact at 5 L and
        seen at 13-22 L, got exponent 0.73 and an offset of -2.9 L."""
        return self._without("offset")

    def quadratic(self) -> "SensorCharacteristic":
        """The three-parameter quadratic variant about the readings' middle (gain, curvature,
        offset): a sensor bent both ways from its calibration point, which no power map follows."""
        rng = self.fixed.get("range")
        span = max(float(rng[1] - rng[0]) if rng else 1.0, 1e-6)
        return type(self)(self.component, {"gain": 1.0, "curvature": 0.0, "offset": self.params.get("offset", 0.0)},
                          {"gain": self.bounds["gain"], "curvature": (-1.0 / span, 1.0 / span),
                           "offset": self.bounds["offset"]}, dict(self.fixed))

    def _without(self, name: str) -> "SensorCharacteristic":
        return type(self)(self.component, {k: v for k, v in self.params.items() if k != name},
                          {k: v for k, v in self.bounds.items() if k != name}, dict(self.fixed))

    def values(self, theta=None) -> dict:
        out = super().values(theta)
        if "curvature" in out:
            return out
        if "exponent" in out:
            out.setdefault("offset", 0.0)
        if "gain" not in out and "exponent" in out:
            out["gain"] = self._tied_gain(out)
        return out

    def negligible(self, p, model):
        s = model.find("sensor", self.component)
        rng = self.fixed.get("range")
        if model.total_volume is not None and drives_no_flow(model, s.tank) and rng is not None:
            # seen through the inventory alone (as an offset there): over the readings' range the
            # map must move the tank's volume beyond the fill's band, or it is the fill's error
            ys = np.linspace(rng[0], rng[1], 21)
            fitted = s.copy() if hasattr(s, "copy") else _copy.copy(s)
            self.edit_sensor(fitted, p)
            q0, q1 = s.invert(ys), fitted.invert(ys)
            scale = model.tank(s.tank).area if s.quantity == "level" else 1.0
            band = INVENTORY_BAND * INVENTORY_SPREAD * model.total_volume
            if float(np.max(np.abs(q1 - q0))) * scale <= band:
                return True
        if "curvature" in p:
            rng = self.fixed.get("range") or (0.0, 1.0)
            straight = abs(p["curvature"]) * (0.5 * (rng[1] - rng[0])) ** 2 < 2.0 * max(s.noise_sigma, s.resolution)
        else:
            straight = abs(p["exponent"] - 1.0) < 0.03
        return straight and abs(p["gain"] - 1.0) < 0.03 and \
            abs(p["offset"]) < max(2.0 * s.noise_sigma, 2.0 * s.resolution)

    def describe(self, p):
        if "curvature" in p:
            return (f"{self.component} = {p['gain']:.3g}*gain*level {p['curvature']:+.3g}*(level - "
                    f"{self.fixed.get('q_mid', 0.0):.3g})**2 {p['offset']:+.3g}")
        return f"{self.component} = {p['gain']:.3g}*gain*level**{p['exponent']:.3g} {p['offset']:+.3g}"


def _rim_anchor(model, loc, s) -> tuple[float, float] | None:
    """(rim quantity, median plateau reading) of a tank whose reading plateaus at or above the
    reading the model gives its rim: the tank is at its rim there (it cannot hold more), whatever
    the sensor's map. The median, not the plateau's top: the map must put the noisy readings at the
    rim, where the overflow holds the tank. None when the tank has no finite rim or no such
    plateau (a plateau below the rim is an overflow candidate's)."""
    tk = model.tank(s.tank)
    rim, vol = tk.rim_volume(), loc.plateaus.get(s.tank)
    reading = loc.plateau_readings.get(s.name)
    if vol is None or reading is None or not np.isfinite(rim) or below_rim(tk, vol):
        return None
    scale = tk.area if s.quantity == "level" else 1.0
    return (rim / scale, float(reading))

