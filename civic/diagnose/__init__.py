"""`civic diagnose`: find what a recording shows that the nominal plant model leaves out.

Layout (PySINDy-like: small pieces, one module per mechanism family):

* `data`       — load a recording (pcap or pcapng in wire format, or CSV) in model signal names
* `nominal`    — fit a nominal model's coefficients on the normal regime of recordings
* `compare`    — equation error (per-tank mass balance) and simulation error
* `locate`     — which components / intervals / operating regimes carry the mismatch
* `mechanisms` — the catalogue: `Mechanism` base class + leak, closure, coefficient, dead_time,
                 valve_characteristic, flow_law, pump_head, pump_dead_zone, overflow,
                 sensor_offset, sensor_characteristic, sensor_saturation
* `problem`    — the fitting problem: calibration (+-5 %), candidates' edits, held-out folds;
                 `Diagnosis`, the state every step reads and adds to
* `forward`    — forward selection on the equation error's held-out blocks, alternatives
* `replay`     — the replay stage, where the balances leave no finding
* `backward`   — free run (unmeasured tanks): joint fit, backward elimination, ablation
* `dating`     — a finding switched on or off mid-run, dated again in the fitted model
* `fit`        — `diagnose()`: the steps above in order, the improved model
* `report`     — JSON report, rich table, plot
* `noise`, `experiments` — noise estimates; the experiment that would separate alternatives
"""
