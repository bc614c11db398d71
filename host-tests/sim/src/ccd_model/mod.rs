//! A charge-transfer model of the CCD47-20, clocked by the sequencer's BSRR words: the proof,
//! without a board, that a compiled table delivers the pixels the core expects.
//!
//! What it models, tick by tick (one word = one tick):
//! - The image and store sections as one chain of gates (three per row, image then store,
//!   each driven by its line). A charge packet (a whole row) sits in a well: a run of
//!   adjacent high gates. When the levels change, each packet goes to the new well that
//!   overlaps its old one; no overlapping well loses the packet, two split it, two packets
//!   into one well merge them (all three are faults). A well that touches the last store
//!   gate empties into the serial register (rows add up there: that is parallel binning).
//! - The serial register as two halves of three-phase elements (left: R1L-R3L, right:
//!   R1R-R3R). All elements of a half share their phases, so one change moves every packet
//!   of the half by the same -1, 0 or +1 element (or loses them all when no new well
//!   overlaps the old). A packet leaving a half's output end goes into the summing well
//!   when SW is high, onto the output node otherwise; one leaving its inner end enters the
//!   other half when that half moves towards its own output (one-output readout), and
//!   collides with it otherwise (a fault).
//! - SW falling moves its charge onto the node; RG high empties the node; DG high drains
//!   the whole register; a CONVST rising edge samples both nodes. A sample taken with RG
//!   high, or before the node settled (the timing's reset settle after RG falls, its signal
//!   settle after SW falls or charge reaches the node), is a fault.
//!
//! Charge is an integer (electrons); there is no noise, so a correct table reproduces the
//! image exactly. Cost: O(1) a serial tick, O(gates + rows) a parallel change; a full
//! CCD47-20 frame (~5 M ticks) runs in about a second.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::sequencer::{Line, LineSet, Phases, PinMap, REST, Ticks};
use std::collections::VecDeque;

/// What went wrong while clocking (all zero for a correct table).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// Packets that no new well overlapped (charge lost or smeared).
    pub lost_packets: u64,
    /// Electrons in the lost packets.
    pub lost_e: i64,
    /// Packets that overlapped two new wells.
    pub split: u64,
    /// Wells that received two packets in the image/store sections.
    pub merged: u64,
    /// Packets pushed into the middle of the register against the other half's flow, or
    /// off a section's far end.
    pub collisions: u64,
    /// States with no well or no barrier in a three-phase group.
    pub no_well: u64,
    /// Samples taken with the reset gate high.
    pub samples_in_reset: u64,
    /// Samples taken before the node settled.
    pub unsettled_samples: u64,
}

impl Faults {
    /// True when nothing went wrong.
    pub fn is_clean(&self) -> bool {
        *self == Self::default()
    }
}

struct Packet {
    lo: usize,
    hi: usize,
    charge: Vec<i64>,
}

/// The CCD's state.
pub struct CcdModel {
    pins: PinMap,
    image_rows: usize,
    par_cols: usize,
    col_offset: usize,
    line_len: usize,
    gate_lines: Vec<Line>,
    packets: Vec<Packet>,
    halves: [VecDeque<i64>; 2],
    port: u16,
    state: LineSet,
    sw_e: [i64; 2],
    node_e: [i64; 2],
    node_ready: [u64; 2],
    serial_dirty: bool,
    tick: u64,
    started: bool,
    reset_settle: u64,
    signal_settle: u64,
    samples: Vec<[i64; 2]>,
    sample_ticks: Vec<u64>,
    /// What went wrong so far.
    pub faults: Faults,
    /// Electrons drained through the dump gate.
    pub dumped_e: i64,
}

const GROUPS_PAR: [[Line; 3]; 2] = [Line::IMAGE, Line::STORE];

impl CcdModel {
    /// A CCD of `geometry` (image `active_rows` deep, store `lines` deep, columns = covered +
    /// active + covered, over-scan elements only in the register), every line at the
    /// sequencer's rest state, the sections empty; `ticks` gives the settling a sample needs.
    pub fn new(geometry: &ReadoutGeometry, pins: PinMap, ticks: &Ticks) -> Self {
        let image_rows = usize::from(geometry.active_rows);
        let store_rows = usize::from(geometry.lines);
        let par_cols = 2 * usize::from(geometry.covered_px) + usize::from(geometry.active_cols);
        let line_len = geometry.line_len();
        let gate_lines = (0..3 * (image_rows + store_rows))
            .map(|g| {
                let group = if g / 3 < image_rows {
                    Line::IMAGE
                } else {
                    Line::STORE
                };
                group[g % 3]
            })
            .collect();
        let half = line_len / 2;
        let port = PinMap::apply(0, pins.bsrr(REST));
        let mut m = Self {
            pins,
            image_rows,
            par_cols,
            col_offset: usize::from(geometry.overscan_px),
            line_len,
            gate_lines,
            packets: Vec::new(),
            halves: [
                VecDeque::from(vec![0; half]),
                VecDeque::from(vec![0; line_len - half]),
            ],
            port,
            state: pins.lines_of_port(port),
            sw_e: [0; 2],
            node_e: [0; 2],
            node_ready: [0; 2],
            serial_dirty: false,
            tick: 0,
            started: false,
            reset_settle: u64::from(ticks.reset_settle),
            signal_settle: u64::from(ticks.signal_settle),
            samples: Vec::new(),
            sample_ticks: Vec::new(),
            faults: Faults::default(),
            dumped_e: 0,
        };
        m.packets = m
            .wells(m.state)
            .into_iter()
            .map(|(lo, hi)| Packet {
                lo,
                hi,
                charge: vec![0; par_cols],
            })
            .collect();
        m
    }

    /// Puts charge `f(column, y)` into every image pixel (`column` over covered + active
    /// columns, `y` = 0 the row nearest the store, read first) and `store(column, row)` into
    /// every store row (what a previous frame left).
    pub fn load(&mut self, f: impl Fn(usize, usize) -> i64, store: impl Fn(usize, usize) -> i64) {
        let image_rows = self.image_rows;
        for p in &mut self.packets {
            let element = p.lo / 3;
            for (c, q) in p.charge.iter_mut().enumerate() {
                *q = if element < image_rows {
                    f(c, image_rows - 1 - element)
                } else {
                    store(c, element - image_rows)
                };
            }
        }
    }

    /// Raw register column of parallel column `c`.
    pub fn raw_col(&self, c: usize) -> usize {
        c + self.col_offset
    }

    /// Parallel columns (covered + active).
    pub fn par_cols(&self) -> usize {
        self.par_cols
    }

    /// The samples taken, `[left, right]` node charge at each CONVST.
    pub fn samples(&self) -> &[[i64; 2]] {
        &self.samples
    }

    /// The tick of each sample (1 = the first word run).
    pub fn sample_ticks(&self) -> &[u64] {
        &self.sample_ticks
    }

    /// Correlated double sampling: signal minus reset level of each sample pair.
    pub fn pixels(&self) -> Vec<[i64; 2]> {
        self.samples
            .chunks_exact(2)
            .map(|p| [p[1][0] - p[0][0], p[1][1] - p[0][1]])
            .collect()
    }

    /// Ticks run so far.
    pub fn ticks(&self) -> u64 {
        self.tick
    }

    /// Runs every word of `words`, one a tick.
    pub fn run(&mut self, words: impl IntoIterator<Item = u32>) {
        for w in words {
            self.step(w);
        }
    }

    fn wells(&self, s: LineSet) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let mut start = None;
        for (g, &line) in self.gate_lines.iter().enumerate() {
            match (s.is_high(line), start) {
                (true, None) => start = Some(g),
                (false, Some(lo)) => {
                    out.push((lo, g - 1));
                    start = None;
                }
                _ => {}
            }
        }
        if let Some(lo) = start {
            out.push((lo, self.gate_lines.len() - 1));
        }
        out
    }

    /// One tick: `word` written to BSRR.
    pub fn step(&mut self, word: u32) {
        self.tick += 1;
        let port = PinMap::apply(self.port, word);
        let new = self.pins.lines_of_port(port);
        // The register starts in whatever state the first word sets (it is empty).
        let old = if self.started {
            self.state
        } else {
            self.started = true;
            self.state
                .phases(Line::REG_LEFT, new.phases_of(Line::REG_LEFT))
                .phases(Line::REG_RIGHT, new.phases_of(Line::REG_RIGHT))
        };
        self.port = port;
        self.state = new;
        if GROUPS_PAR
            .iter()
            .any(|g| old.phases_of(*g) != new.phases_of(*g))
        {
            self.parallel(old, new);
        }
        let moves = [
            reg_move(old.phases_of(Line::REG_LEFT), new.phases_of(Line::REG_LEFT)),
            reg_move(
                old.phases_of(Line::REG_RIGHT),
                new.phases_of(Line::REG_RIGHT),
            ),
        ];
        self.serial(moves, new);
        let t = self.tick;
        if old.is_high(Line::Sw) && !new.is_high(Line::Sw) {
            for o in 0..2 {
                self.node_e[o] += std::mem::take(&mut self.sw_e[o]);
                self.node_ready[o] = t + self.signal_settle;
            }
        }
        if new.is_high(Line::Rg) {
            self.node_e = [0; 2];
        }
        if old.is_high(Line::Rg) && !new.is_high(Line::Rg) {
            self.node_ready = [t + self.reset_settle; 2];
        }
        if new.is_high(Line::Dg) && self.serial_dirty {
            for h in &mut self.halves {
                for q in h.iter_mut() {
                    self.dumped_e += std::mem::take(q);
                }
            }
            self.serial_dirty = false;
        }
        if new.is_high(Line::Convst) && !old.is_high(Line::Convst) {
            if new.is_high(Line::Rg) {
                self.faults.samples_in_reset += 1;
            }
            if self.node_ready.iter().any(|&r| t < r) {
                self.faults.unsettled_samples += 1;
            }
            self.samples.push(self.node_e);
            self.sample_ticks.push(t);
        }
    }

    fn parallel(&mut self, old: LineSet, new: LineSet) {
        for g in GROUPS_PAR {
            for s in [old, new] {
                let n = s.phases_of(g).0.count_ones();
                if n == 0 || n == 3 {
                    self.faults.no_well += 1;
                }
            }
        }
        let wells = self.wells(new);
        let mut placed: Vec<Option<Vec<i64>>> = vec![None; wells.len()];
        let mut j = 0;
        for p in std::mem::take(&mut self.packets) {
            while j < wells.len() && wells.get(j).is_some_and(|w| w.1 < p.lo) {
                j += 1;
            }
            let mut hits =
                (j..wells.len()).take_while(|&k| wells.get(k).is_some_and(|w| w.0 <= p.hi));
            let Some(first) = hits.next() else {
                self.faults.lost_packets += 1;
                self.faults.lost_e += p.charge.iter().sum::<i64>();
                continue;
            };
            if hits.next().is_some() {
                self.faults.split += 1;
            }
            match placed.get_mut(first) {
                Some(Some(existing)) => {
                    self.faults.merged += 1;
                    for (a, b) in existing.iter_mut().zip(&p.charge) {
                        *a += b;
                    }
                }
                Some(slot) => *slot = Some(p.charge),
                None => {}
            }
        }
        let last_gate = self.gate_lines.len() - 1;
        let dg = new.is_high(Line::Dg);
        let mut packets = Vec::with_capacity(wells.len());
        for ((lo, hi), charge) in wells.into_iter().zip(placed) {
            let charge = charge.unwrap_or_else(|| vec![0; self.par_cols]);
            if hi == last_gate {
                self.deposit_row(&charge, dg);
            } else {
                packets.push(Packet { lo, hi, charge });
            }
        }
        self.packets = packets;
    }

    fn deposit_row(&mut self, row: &[i64], dg: bool) {
        if dg {
            self.dumped_e += row.iter().sum::<i64>();
            return;
        }
        let half = self.halves[0].len();
        for (c, &q) in row.iter().enumerate() {
            let r = c + self.col_offset;
            let slot = if r < half {
                self.halves[0].get_mut(r)
            } else {
                self.halves[1].get_mut(self.line_len - 1 - r)
            };
            if let Some(s) = slot {
                *s += q;
            }
        }
        self.serial_dirty = true;
    }

    fn serial(&mut self, moves: [Option<i8>; 2], new: LineSet) {
        let mut to_middle = [None, None];
        for (h, m) in moves.iter().enumerate() {
            match m {
                None => {
                    self.faults.no_well += 1;
                }
                Some(-1) => {
                    let q = self.halves[h].pop_back().unwrap_or(0);
                    self.halves[h].push_front(0);
                    to_middle[h] = Some(q);
                }
                Some(2) => {
                    // No new well overlaps the old: every packet of the half is lost.
                    for q in self.halves[h].iter_mut() {
                        let q = std::mem::take(q);
                        if q != 0 {
                            self.faults.lost_packets += 1;
                            self.faults.lost_e += q;
                        }
                    }
                }
                _ => {}
            }
        }
        for h in 0..2 {
            if moves[h] == Some(1) {
                let q = self.halves[h].pop_front().unwrap_or(0);
                let incoming = to_middle[1 - h].take().unwrap_or(0);
                self.halves[h].push_back(incoming);
                if new.is_high(Line::Sw) {
                    self.sw_e[h] += q;
                } else {
                    self.node_e[h] += q;
                    self.node_ready[h] = self.tick + self.signal_settle;
                }
            }
        }
        for (h, left_over) in to_middle.iter_mut().enumerate() {
            if let Some(q) = left_over.take() {
                if q != 0 {
                    self.faults.collisions += 1;
                }
                if let Some(b) = self.halves[1 - h].back_mut() {
                    *b += q;
                }
            }
        }
    }
}

/// Gates of a three-phase well as a run on a line where element `e`'s phases are gates
/// `3e`, `3e+1`, `3e+2` (transfer direction = increasing gate): `(start, len)`.
fn run_of(p: Phases) -> Option<(i32, i32)> {
    match p.0 & 7 {
        0b001 => Some((0, 1)),
        0b010 => Some((1, 1)),
        0b100 => Some((2, 1)),
        0b011 => Some((0, 2)),
        0b110 => Some((1, 2)),
        0b101 => Some((2, 2)),
        _ => None,
    }
}

/// How a register half's packets move when its phases go from `old` to `new`: `Some(d)` with
/// `d` in -1..=1 elements (towards the output is +1), `Some(2)` when no new well overlaps
/// the old one (the packets are lost), `None` when either state has no well or no barrier.
fn reg_move(old: Phases, new: Phases) -> Option<i8> {
    if old == new {
        return run_of(new).map(|_| 0);
    }
    let (os, ol) = run_of(old)?;
    let (ns, nl) = run_of(new)?;
    for d in -1..=1i32 {
        let s = ns + 3 * d;
        if s < os + ol && os < s + nl {
            return Some(d as i8);
        }
    }
    Some(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn register_moves() {
        for (seq, d) in [
            (Phases::FORWARD_FROM_P31, 1),
            (Phases::BACKWARD_FROM_P31, -1),
        ] {
            let mut prev = Phases::P31;
            let mut total = 0;
            for p in seq {
                total += reg_move(prev, p).unwrap_or(9);
                prev = p;
            }
            assert_eq!(total, d);
        }
        assert_eq!(reg_move(Phases::P12, Phases(0b100)), Some(2));
        assert_eq!(reg_move(Phases::P12, Phases(0b111)), None);
    }
}
