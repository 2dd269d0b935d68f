"""`civic configure --read`: installed entries and per-plant register state."""
from __future__ import annotations

from civic.cli import main
from civic.switch.connection import SwitchConnection
from civic.switch.converge import read_state
from civic.switch.pipeline import ensure_pipeline
from civic.switch.registers import monitor_config, read_plant_state
from civic.switch.schema import REGISTER_LAST_SEQ, mon

from switch.p4rt_servicer import entries_file


def test_cli_summary_and_read(servicer, tmp_path, capsys):
    path = entries_file(tmp_path)
    assert main(["configure", "--switch", servicer.address, "--entries", str(path)]) == 0
    out = capsys.readouterr().out
    assert "added" in out and "unchanged" in out and "11" in out
    # registers of plant 10.0.0.1 (slot 1) as the P4 program would leave them
    with servicer.lock:
        reg = lambda name: servicer.registers[servicer.by_name(name)]
        reg(REGISTER_LAST_SEQ)[1] = 4242
        reg(mon(0, "ptr"))[1] = 2
        reg(mon(0, "run"))[1] = 7
        reg(mon(0, "s0"))[1] = 600
        for i in range(20):
            reg(mon(0, "ring"))[1 * 128 + i] = 100 + i
        reg(REGISTER_LAST_SEQ)[9] = 5                      # another plant
    servicer.primary_floor = 100                 # another controller is primary: reading needs no session
    assert main(["configure", "--switch", servicer.address, "--read", "--plant", "10.0.0.1"]) == 0
    out = capsys.readouterr().out
    assert "4242" in out and "mon0" in out and "mon1" in out and "600" in out
    ring = " ".join(str(100 + (2 + i) % 20) for i in range(20))   # oldest first: starts at ptr
    assert ring.split()[:3] == ["102", "103", "104"]
    assert "102 103 104" in out.replace("\n", " ").replace("│", " ").replace("  ", " ")
    assert "set_class(cls=3)" in out and "slope=[-2147483648, -41000]" in out
    states = None
    with SwitchConnection(servicer.address) as conn:
        sch, _ = ensure_pipeline(conn, None)
        _, defaults = read_state(conn, sch)
        states = read_plant_state(conn, sch, monitor_config(sch, defaults))
    assert [s.slot for s in states] == [1, 9]
    assert states[0].monitors[0]["ring"] == [100 + (2 + i) % 20 for i in range(20)]
    assert len(states[0].monitors[1]["ring"]) == 8 and states[0].monitors[2] is None
    assert main(["configure", "--switch", servicer.address, "--read", "--plant", "10.0.1.1",
                 "--entries", str(path)]) == 2
    assert "outside the plant prefix 10.0.0.0/24" in capsys.readouterr().err


# ---------------------------------------------------------------- register state on reconfiguration
