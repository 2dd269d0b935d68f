"""The P4Runtime session: one-line errors for bad entries and unreachable switches, election ids."""
from __future__ import annotations

import copy

import pytest

from civic.cli import main
from civic.errors import CivicError
from civic.switch.converge import configure

from switch.p4rt_servicer import ENTRIES, entries_file


@pytest.mark.parametrize("mutate, message", [
    (lambda r: r["monitors"][0]["precondition"].update(p9=[0, 1]), "precondition.p9: unknown field"),
    (lambda r: r["monitors"][0]["classes"][0].update(slope=[-2**31, -20000]), "entries 0 and 1 overlap"),
    (lambda r: r.update(udp_port=70000), "udp_port: 70000 is outside 1..65535"),
])
def test_cli_bad_entries_one_line_exit_2(servicer, tmp_path, capsys, mutate, message):
    raw = copy.deepcopy(ENTRIES)
    mutate(raw)
    code = main(["configure", "--switch", servicer.address, "--entries", str(entries_file(tmp_path, raw))])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert servicer.writes == []


def test_cli_unreachable_switch_one_line(tmp_path, capsys):
    import socket
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                   # nothing listens there now
    code = main(["configure", "--switch", f"127.0.0.1:{port}", "--entries", str(entries_file(tmp_path)),
                 "--timeout", "0.5"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines() == [f"civic configure: error: cannot reach switch 127.0.0.1:{port} "
                                "(no P4Runtime server answered within 0.5 s)"]


def test_not_primary_refuses_to_write(servicer, tmp_path):
    servicer.primary_floor = 10
    with pytest.raises(CivicError, match="another controller is primary"):
        configure(servicer.address, entries_file(tmp_path), election_id=3)
    assert servicer.writes == []
    res = configure(servicer.address, entries_file(tmp_path), election_id=11)
    assert res.added == 11 and all(w.election_id.low == 11 for w in servicer.writes)
