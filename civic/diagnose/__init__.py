"""`civic diagnose`: find what a recording shows that the nominal plant model leaves out.

Layout (PySINDy-like: small pieces, one module per mechanism family):

* `data`      — load a recording (pcap wire format or CSV) in model signal names
* `compare`   — equation error (per-tank mass balance) and simulation error
* `locate`    — which components / intervals / operating regimes carry the mismatch
* `mechanisms`— the catalogue: `Mechanism` base class + leak, dead_time,
                valve_characteristic, pump_head, overflow, sensor_offset,
                sensor_saturation, coefficient
* `fit`       — calibration (+-5 %), candidate fits, held-out selection
* `report`    — JSON report, rich table, plot
"""
