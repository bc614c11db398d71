//! The simulated sensor as the link's diagnostic window source: the frame after a window
//! request rendered (raw) or rendered and calibrated as the tracker calibrates a window. Cost:
//! a raw window renders only its pixels; a calibrated one renders the whole frame once (each
//! line's bias comes from its own over-scan).

use startrack_core::calib::{FrameCalibration, LineLevels};
use startrack_core::link::{WindowKind, WindowReader, WindowRequest};
use startrack_core::window::Rect;
use startrack_sim::sim::{SensorParams, Simulator, Star};

/// Diagnostic windows from the simulated sensor, of the frame after the request: raw, or
/// calibrated as the tracker calibrates a window (each line's bias from its own over-scan,
/// then the per-pixel formula with the tracker's calibration: its table, dark scale, exposure
/// and temperature, [`startrack_core::tracker::Tracker::calibration`]), in e- x 64.
pub struct SimWindows {
    /// The sensor.
    pub params: SensorParams,
    /// The stars of the frame to render.
    pub stars: Vec<Star>,
    /// Its stars that move during the exposure ([`Simulator::trails`]).
    pub trails: Vec<startrack_sim::trail::TrailedImage>,
    /// Its frame number (the noise draw).
    pub frame: u32,
    /// The tracker's calibration (calibrated windows need one).
    pub calibration: Option<FrameCalibration<'static>>,
    rendered: Option<(WindowRequest, Vec<i32>)>,
}

impl SimWindows {
    /// A source for `params`' sensor.
    pub fn new(params: SensorParams) -> Self {
        Self {
            params,
            stars: Vec::new(),
            trails: Vec::new(),
            frame: 0,
            calibration: None,
            rendered: None,
        }
    }
}

impl WindowReader for SimWindows {
    fn check(&mut self, r: &WindowRequest) -> bool {
        let g = self.params.geometry;
        let inside = u32::from(r.x0) + u32::from(r.side_px) <= u32::from(g.active_cols)
            && u32::from(r.y0) + u32::from(r.side_px) <= u32::from(g.active_rows);
        if !inside {
            return false;
        }
        let sim = Simulator {
            frame: self.frame,
            trails: self.trails.clone(),
            ..Simulator::new(self.params.clone(), self.stars.clone())
        };
        let rect = Rect {
            x0: r.x0,
            y0: r.y0,
            width: r.side_px,
            height: r.side_px,
        };
        let px = match r.kind {
            WindowKind::Raw => sim.render_window(rect).into_iter().map(i32::from).collect(),
            WindowKind::Calibrated => {
                let Some(cal) = self.calibration else {
                    return false;
                };
                match calibrated_window(&sim, &cal, rect) {
                    Some(px) => px,
                    None => return false,
                }
            }
        };
        self.rendered = Some((*r, px));
        true
    }

    fn read_row(&mut self, r: &WindowRequest, row: u16, out: &mut [i32]) -> bool {
        let Some((req, px)) = &self.rendered else {
            return false;
        };
        if req != r {
            return false;
        }
        let side = usize::from(r.side_px);
        let start = usize::from(row) * side;
        match px.get(start..start + side) {
            Some(src) if out.len() == side => {
                out.copy_from_slice(src);
                true
            }
            _ => false,
        }
    }
}

/// Window `rect` of `sim`'s frame calibrated with `cal`, e- x 64 (I26F6 bits).
fn calibrated_window(sim: &Simulator, cal: &FrameCalibration<'_>, rect: Rect) -> Option<Vec<i32>> {
    let raw = crate::demo::render_frame(sim);
    let g = sim.params.geometry;
    let lines = raw
        .chunks_exact(g.line_len())
        .map(|l| LineLevels::measure(&g, l))
        .collect::<Result<Vec<_>, _>>()
        .ok()?;
    let levels = crate::home::FrameLevels {
        geometry: g,
        lines,
        dark_scale_e: None,
    };
    let (e, _, _) = levels.calibrate_window(cal, &raw, rect).ok()?;
    Some(e.into_iter().map(|v| v.to_bits()).collect())
}
