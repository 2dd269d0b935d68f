"""The switch as one compiled pass per message (numba): the streaming form of the model.

`StreamingSwitch.process(buf, offset, plant)` runs a chunk of frames through the registers
the switch keeps (the ones of `SwitchModel.step`, carried from the previous chunk), writes
each plant message's verdict and UDP checksum into the frame, and returns the verdict
changes. Any chunking gives the bytes of one whole-file pass.

The kernel is `SwitchModel.step` compiled: one function per P4 control (plant lookup,
balance, data collection, slope, classification, notify, verdict), in the order of
control/ingress.p4, over registers held in numpy arrays. Tables are the entries'
RangeTables (classification.py) packed into flat arrays (`TablePack`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from civic.config import PRECONDITION_FIELDS
from civic.entries import BALANCE_SHIFT, BAND_SUM_SHIFT, Entries
from civic.pipeline import notify, plant_lookup
from civic.pipeline.classification import HOLD_MAX, SLOPE_BIAS, RangeTable, range_table, slope_key
from civic.pipeline.data_collection import RUN_MAX
from civic.wire import Capture, frame_heads, OFF_IP, OFF_PAYLOAD, OFF_UDP_CSUM, OFF_VERDICT, SIGNALS

U16, U32 = 0xFFFF, 0xFFFFFFFF
KINDS = {"slope": 0, "balance": 1, "limit": 2}
ESTIMATORS = {"lsq": 0, "endpoint": 1, "value": 2}
OPERANDS = {**{s: i for i, s in enumerate(SIGNALS)}, "zero": -1}     # a flow term's key: a field or 0
FIELDS = len(PRECONDITION_FIELDS)                                     # wire fields, then command steps
CHUNK = 65536                  # messages per kernel call: bounds the change buffer
CHANGE_COLUMNS = ("index", "monitor", "prev", "cls", "slope", "level")
OFF_SRC = OFF_IP + 12
OFF_SIGNALS = OFF_PAYLOAD + 4
REGS = ("ptr", "run", "s0", "s1", "acc", "accb", "cand", "hold", "last_class")   # per monitor and plant
PTR, RUN, S0, S1, ACC, ACCB, CAND, HOLD, LAST = range(len(REGS))
CONFIG = ("kind", "estimator", "window", "ring_len", "hold", "signal", "aux_plus", "aux_minus",
          "compensate_table", "class_table", "first_term", "end_term")          # per monitor
KIND, EST, WIN, RLEN, MINHOLD, SIG, AUXP, AUXM, COMP, CLS, T0, T1 = range(len(CONFIG))
# no reference counting: the kernel allocates nothing, and counting every array handed from
# control to control cost more than the controls
JIT = {"cache": True, "_nrt": False}
INLINE = {**JIT, "inline": "always"}


class TablePack:
    """Range tables as flat arrays for the kernel. Table t (a row of `meta`): key j's edges are
    edges[meta[t, j]: meta[t, j] + meta[t, 2 + j]] (length -1: no second key); the cell
    (i0, i1) holds results[meta[t, 4] + i0 * (meta[t, 3] + 1) + i1]; i_j of a 16-bit key is
    luts[meta[t, 5 + j], key] (-1: no LUT, bisect the edges), one load instead of a search."""

    def __init__(self):
        self.edges, self.results, self.meta, self.luts = [], [], [], []
        self._edges_n = self._cells_n = 0

    def add(self, table: RangeTable, values: np.ndarray, miss: tuple[int, int],
            narrow: tuple[bool, ...] = (True, True)) -> int:
        """Append a table whose entry r gives values[r] (two columns), a miss `miss`; narrow[j]:
        key j is usually 16 bit (it gets a LUT). Returns the table's id."""
        offs, lens, luts = [0, 0], [-1, -1], [-1, -1]
        for j, e in enumerate(table.edges):
            offs[j], lens[j] = self._edges_n, len(e)
            self.edges.append(e)
            self._edges_n += len(e)
            if narrow[j] and len(e) < U16:
                luts[j] = len(self.luts)
                self.luts.append(np.searchsorted(e, np.arange(U16 + 1), "right").astype(np.uint16))
        grid = table.grid.reshape(-1)
        cells = np.tile(np.asarray(miss, np.int64), (len(grid), 1))
        cells[grid >= 0] = values[grid[grid >= 0]]
        self.meta.append((*offs, *lens, self._cells_n, *luts))
        self.results.append(cells)
        self._cells_n += len(cells)
        return len(self.meta) - 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        edges = np.concatenate(self.edges) if self.edges else np.zeros(1, np.int64)
        results = np.concatenate(self.results) if self.results else np.zeros((1, 2), np.int64)
        luts = np.stack(self.luts) if self.luts else np.zeros((1, U16 + 1), np.uint16)
        return (np.ascontiguousarray(edges, np.int64), np.ascontiguousarray(results, np.int64),
                np.asarray(self.meta, np.int64).reshape(-1, 7), luts)


def _table(rows: np.ndarray, keys: int, values: np.ndarray) -> tuple[RangeTable, np.ndarray]:
    """A RangeTable on rows' first `keys` (lo, hi) column pairs and its entries' two result columns."""
    rows = np.asarray(rows, np.int64)
    if not len(rows):        # an empty table: one cell, a miss
        lo = np.zeros((0, keys), np.int64)
        return RangeTable(lo, lo), np.zeros((0, 2), np.int64)
    return range_table(rows, keys), np.asarray(values, np.int64).reshape(len(rows), 2)


class StreamingSwitch:
    """The software switch over a stream of message chunks, registers kept between them."""

    def __init__(self, entries: Entries):
        self.entries = entries
        self.plants = plant_lookup.MAX_PLANTS     # every slot (an IPv4 source's last octet) has its cells
        mons = entries.monitors
        n = len(mons)
        pack = TablePack()
        cfg = np.zeros((n, len(CONFIG)), np.int64)
        pre = np.zeros((n, FIELDS, 2), np.int64)
        term_rows = []
        for m, mon in enumerate(mons):
            pre[m] = mon.ranges()
            off_rows = mon.offsets
            comp = pack.add(*_table(off_rows, 1, np.c_[off_rows[:, 2:3], np.zeros((len(off_rows), 1), np.int64)]),
                            miss=(0, 0))
            rows = np.asarray(mon.classes, np.int64).copy()
            rows[:, 0], rows[:, 1] = slope_key(rows[:, 0]), slope_key(rows[:, 1])
            cls = pack.add(*_table(rows, 2, np.c_[rows[:, 4:5], np.zeros((len(rows), 1), np.int64)]),
                           miss=(mon.default_class, 0), narrow=(False, True))   # keys: slope, level
            first = len(term_rows)
            for term in mon.terms:
                tid = pack.add(*_table(term.rows, 2, term.rows[:, 4:6]), miss=(0, 0))
                term_rows.append((OPERANDS[term.head[0]], OPERANDS[term.head[1]], OPERANDS[term.command], tid))
            plus, minus = mon.aux_signals
            cfg[m] = (KINDS[mon.kind], ESTIMATORS[mon.estimator], mon.window, mon.ring_len, mon.hold,
                      SIGNALS.index(mon.signal), SIGNALS.index(plus), SIGNALS.index(minus), comp, cls,
                      first, len(term_rows))
        self.cfg, self.pre = cfg, pre
        self.terms = np.asarray(term_rows, np.int64).reshape(-1, 4)
        self.edges, self.results, self.meta, self.luts = pack.arrays()
        self.rows = np.empty((CHUNK * n, len(CHANGE_COLUMNS)), np.int64)   # changes of one kernel call
        self.fields = np.zeros(FIELDS, np.int64)                           # one message's fields
        self.reset()

    def reset(self) -> None:
        """Zero every register, as a freshly started switch."""
        n, p = len(self.entries.monitors), self.plants
        ring = max([m.ring_len for m in self.entries.monitors] or [1])
        self.last_seq = np.zeros(p, np.int64)
        self.last_cmd = np.zeros((3, p), np.int64)
        self.ring = np.zeros((n, p, ring), np.int64)
        self.ringb = np.zeros((n, p, ring), np.int64)
        self.regs = np.zeros((n, p, len(REGS)), np.int64)
        self.counts = np.zeros((n, p, notify.CLASSES), np.int64)
        self.given = 0                     # plant messages that got a verdict (any monitor)

    def process(self, buf: np.ndarray, offset: np.ndarray, plant: np.ndarray) -> np.ndarray:
        """Run a chunk of frames (uint8 `buf`, frame starts `offset`, `plant` the parser's mask)
        through the switch: verdicts and checksums are written into `buf`; returns the verdict
        changes as rows of CHANGE_COLUMNS, index = the frame's position in `offset`."""
        n = len(offset)
        found = []
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            k, given = ingress(buf, offset[a:b], plant[a:b], self.rows, self.fields, self.cfg, self.pre, self.terms, self.edges,
                        self.luts, self.results, self.meta, self.last_seq, self.last_cmd, self.ring, self.ringb,
                        self.regs, self.counts)
            self.given += given
            rows = self.rows[:k].copy()
            rows[:, 0] += a
            found.append(rows)
        return np.concatenate(found) if found else np.zeros((0, len(CHANGE_COLUMNS)), np.int64)

    def run_capture(self, capture: Capture, base: int = 0) -> list[notify.Change]:
        """A whole Capture through the switch, its frames patched in place (and its decoded
        verdicts and checksums); the verdict changes, indices + base."""
        buf = np.frombuffer(capture.data, np.uint8)
        rows = self.process(buf, capture.offset, capture.messages["plant"])
        msgs = capture.messages
        head = frame_heads(buf, capture.offset, capture.caplen)
        plant = msgs["plant"]
        msgs["verdict"][plant], msgs["udp_csum"][plant] = head["verdict"][plant], head["udp_csum"][plant]
        return changes(rows, msgs["src"], msgs["seq"], base)


def changes(rows: np.ndarray, src: np.ndarray, seq: np.ndarray, base: int = 0) -> list[notify.Change]:
    """`StreamingSwitch.process` rows as notify.Change; src and seq per frame, index + base."""
    return [notify.Change(int(i) + base, int(src[i]), int(mon), int(prev), int(cls), int(seq[i]), int(s),
                          int(x)) for i, mon, prev, cls, s, x in rows]



@njit(**INLINE)
def _edge(edges, off, n, key):
    """searchsorted(edges[off:off+n], key, 'right'): how many edges are <= key. (A plain
    bisection: levels and commands change slowly, so its branches are well predicted; a
    branch-free one measured slower.)"""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) >> 1
        if edges[off + mid] <= key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(**INLINE)
def _index(edges, luts, off, n, lut, key):
    """Which interval of a key's edges holds key: the LUT for a 16-bit key, else a bisection."""
    if lut >= 0 and key <= U16:
        return np.int64(luts[lut, key])
    return _edge(edges, off, n, key)


@njit(**INLINE)
def lookup(edges, luts, meta, t, key0, key1):
    """Cell of table t holding (key0, key1): its row in the packed results."""
    i0 = _index(edges, luts, meta[t, 0], meta[t, 2], meta[t, 5], key0)
    if meta[t, 3] < 0:
        return meta[t, 4] + i0
    return meta[t, 4] + i0 * (meta[t, 3] + 1) + _index(edges, luts, meta[t, 1], meta[t, 3], meta[t, 6], key1)


@njit(**INLINE)
def to_int32(v):
    v = v & U32
    return v - (1 << 32) if v >= (1 << 31) else v


@njit(**INLINE)
def operand(f, k):
    return 0 if k < 0 else f[k]


@njit(**INLINE)
def balance(f, m, slot, x, cfg, terms, edges, luts, results, meta, regs, ringb):
    """control/balance.p4: expected flows summed and accumulated; (z, key2) for the monitor."""
    e = 0
    band = 0
    for t in range(cfg[m, T0], cfg[m, T1]):
        head = (operand(f, terms[t, 0]) - operand(f, terms[t, 1])) & U16
        r = lookup(edges, luts, meta, terms[t, 3], head, operand(f, terms[t, 2]))
        e += results[r, 0]
        band += results[r, 1]
    acc = (regs[m, slot, ACC] + (e & U32)) & U32
    regs[m, slot, ACC] = acc
    z = ((x << BALANCE_SHIFT) - acc) & U32
    accb = (regs[m, slot, ACCB] + (band & U16)) & U32
    regs[m, slot, ACCB] = accb
    p = regs[m, slot, PTR]                       # the ring's cell, before the push moves it
    oldb = ringb[m, slot, p]
    ringb[m, slot, p] = accb
    return z, ((accb - oldb) & U32) >> BAND_SUM_SHIFT


@njit(**INLINE)
def data_collection(m, slot, z, cfg, regs, ring):
    """control/monitor.p4's ring push: write z, move the pointer, update s0 and s1; the old value."""
    rlen = cfg[m, RLEN]
    p = regs[m, slot, PTR]
    old = ring[m, slot, p]
    ring[m, slot, p] = z & U32
    regs[m, slot, PTR] = 0 if p + 1 == rlen else p + 1
    s0 = regs[m, slot, S0]
    regs[m, slot, S1] = (regs[m, slot, S1] + s0 - rlen * old) & U32
    regs[m, slot, S0] = (s0 + z - old) & U32
    return old


@njit(**INLINE)
def slope(m, slot, z, old, cfg, regs):
    """control/slope.p4: the monitor's estimator."""
    est = cfg[m, EST]
    if est == 0:
        return to_int32((cfg[m, WIN] - 1) * regs[m, slot, S0] - 2 * regs[m, slot, S1])
    if est == 1:
        return to_int32(z - old)
    return to_int32(z)


@njit(**INLINE)
def classification(f, m, slot, s, key2, cfg, edges, luts, results, meta, regs):
    """Compensate and classify tables, then the hold: the class written (0: none)."""
    a = max(f[cfg[m, AUXP]] - f[cfg[m, AUXM]], 0)
    resid = to_int32(s - results[lookup(edges, luts, meta, cfg[m, COMP], a, 0), 0])
    c_raw = 0
    if regs[m, slot, RUN] >= cfg[m, WIN]:
        c_raw = results[lookup(edges, luts, meta, cfg[m, CLS], (resid & U32) ^ SLOPE_BIAS, key2), 0]
    if c_raw == regs[m, slot, CAND]:
        regs[m, slot, HOLD] = min(regs[m, slot, HOLD] + 1, HOLD_MAX)
    else:
        regs[m, slot, CAND] = c_raw
        regs[m, slot, HOLD] = 1
    return c_raw if regs[m, slot, HOLD] >= cfg[m, MINHOLD] else 0


@njit(**INLINE)
def u16(buf, o):
    return (np.int64(buf[o]) << 8) | buf[o + 1]


@njit(**INLINE)
def verdict(buf, o, v):
    """control/verdict.p4: the verdict into the frame, the UDP checksum updated (RFC 1624 eq. 3)."""
    csum = u16(buf, o + OFF_UDP_CSUM)
    old = u16(buf, o + OFF_VERDICT)
    buf[o + OFF_VERDICT], buf[o + OFF_VERDICT + 1] = v >> 8, v & 0xFF
    if csum != 0:                        # 0: the sender computed no checksum
        t = ((~csum) & U16) + ((~old) & U16) + v
        t = (t & U16) + (t >> 16)
        t = (t & U16) + (t >> 16)
        out = (~t) & U16
        if out == 0:
            out = U16
        buf[o + OFF_UDP_CSUM], buf[o + OFF_UDP_CSUM + 1] = out >> 8, out & 0xFF


@njit(**JIT)
def ingress(buf, offset, plant, changes, f, cfg, pre, terms, edges, luts, results, meta, last_seq, last_cmd, ring, ringb,
            regs, counts):
    """Every plant message of a chunk of frames through the switch, verdicts written into the
    frames; rows of the verdict changes written to `changes`. Returns (rows written, plant
    messages that got a verdict)."""
    k = 0
    given = 0
    for i in range(len(offset)):
        if not plant[i]:
            continue
        o = offset[i]
        src = u16(buf, o + OFF_SRC + 2)                        # plant_lookup: slot = last octet
        slot = src & 0xFF
        seq = (u16(buf, o + OFF_PAYLOAD) << 16) | u16(buf, o + OFF_PAYLOAD + 2)
        gap = seq != ((last_seq[slot] + 1) & U32)
        last_seq[slot] = seq
        for j in range(7):
            f[j] = u16(buf, o + OFF_SIGNALS + 2 * j)
        for c in range(3):                                     # command steps
            f[7 + c] = abs(f[4 + c] - last_cmd[c, slot])
            last_cmd[c, slot] = f[4 + c]
        v = 0
        for m in range(cfg.shape[0]):
            q = True                                           # precondition
            for j in range(FIELDS):
                if f[j] < pre[m, j, 0] or f[j] > pre[m, j, 1]:
                    q = False
                    break
            run = regs[m, slot, RUN]
            regs[m, slot, RUN] = 0 if not q else (1 if gap else min(run + 1, RUN_MAX))
            x = f[cfg[m, SIG]]
            z, key2 = x, x
            if cfg[m, KIND] == 1:
                z, key2 = balance(f, m, slot, x, cfg, terms, edges, luts, results, meta, regs, ringb)
            old = data_collection(m, slot, z, cfg, regs, ring)
            s = slope(m, slot, z, old, cfg, regs)
            code = classification(f, m, slot, s, key2, cfg, edges, luts, results, meta, regs)
            if code:                                           # notify
                counts[m, slot, code] += 1
                prev = regs[m, slot, LAST]
                if code != prev:
                    changes[k, 0], changes[k, 1], changes[k, 2] = i, m, prev
                    changes[k, 3], changes[k, 4], changes[k, 5] = code, s, x
                    k += 1
                    regs[m, slot, LAST] = code
            v |= code << (2 * m)
        verdict(buf, o, v)
        given += v != 0
    return k, given
