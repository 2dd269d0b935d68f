"""The mechanism catalogue: one module per family, all subclasses of `Mechanism`."""
from .base import Mechanism
from .closure import Closure
from .coefficient import Coefficient, coefficient_paths
from .dead_time import DeadTime
from .flow_law import FlowLaw
from .leak import Leak
from .overflow import Overflow, Spill, SpillOut, Weir
from .pump_dead_zone import PumpDeadZone
from .pump_head import PumpHead
from .sensor_characteristic import SensorCharacteristic
from .sensor_offset import SensorOffset
from .sensor_saturation import SensorSaturation
from .valve_characteristic import ValveCharacteristic

CATALOGUE = (Leak, DeadTime, ValveCharacteristic, PumpHead, Overflow, Spill, Weir, SpillOut, SensorOffset,
             SensorSaturation, Coefficient, FlowLaw, SensorCharacteristic, PumpDeadZone, Closure)

__all__ = ["Mechanism", "CATALOGUE", "Leak", "DeadTime", "ValveCharacteristic", "PumpHead", "Overflow", "Spill",
           "Weir", "SpillOut", "SensorOffset", "SensorSaturation", "Coefficient", "coefficient_paths", "FlowLaw",
           "SensorCharacteristic", "PumpDeadZone", "Closure"]
