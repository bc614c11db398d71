//! A rectangle of calibrated pixels: what detection hands to centroiding.
//!
//! Coordinates are active-area coordinates: 0-based, `x` = column, `y` = row, pixel centres at
//! integers. A window may be clipped by the edge of the active area; the clip is recorded so
//! that centroiding can flag it.

use crate::units::Electrons;

/// A rectangle of the active area: `x0..x0+width`, `y0..y0+height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rect {
    /// Active column of the left edge.
    pub x0: u16,
    /// Active row of the top edge.
    pub y0: u16,
    /// Width in pixels.
    pub width: u16,
    /// Height in pixels.
    pub height: u16,
}

impl Rect {
    /// Number of pixels.
    pub const fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// True when the rectangle holds no pixel.
    pub const fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }

    /// True when active pixel (x, y) lies inside.
    pub const fn contains(&self, x: u16, y: u16) -> bool {
        x >= self.x0 && y >= self.y0 && (x - self.x0) < self.width && (y - self.y0) < self.height
    }

    /// An `n` x `n` square centred on (cx, cy) and clipped to an active area of
    /// `cols` x `rows`, with a flag telling whether clipping removed any pixel.
    pub fn centred_clipped(cx: u16, cy: u16, n: u16, cols: u16, rows: u16) -> (Rect, bool) {
        let half = n / 2;
        let x0 = cx.saturating_sub(half);
        let y0 = cy.saturating_sub(half);
        let x1 = (u32::from(cx) + u32::from(n - half)).min(u32::from(cols)) as u16;
        let y1 = (u32::from(cy) + u32::from(n - half)).min(u32::from(rows)) as u16;
        let r = Rect {
            x0,
            y0,
            width: x1.saturating_sub(x0),
            height: y1.saturating_sub(y0),
        };
        let clipped = r.width != n || r.height != n;
        (r, clipped)
    }

    /// An `n` x `n` square centred on active pixel (cx, cy) and clipped to this rectangle, in
    /// active coordinates (a star's sub-window inside a larger window); whether it lost a
    /// pixel is `width < n || height < n`.
    pub fn centred_within(&self, cx: u16, cy: u16, n: u16) -> Rect {
        let (rel, _) = Rect::centred_clipped(
            cx.saturating_sub(self.x0),
            cy.saturating_sub(self.y0),
            n,
            self.width,
            self.height,
        );
        Rect {
            x0: self.x0.saturating_add(rel.x0),
            y0: self.y0.saturating_add(rel.y0),
            ..rel
        }
    }
}

/// Calibrated pixels of a [`Rect`], row-major, borrowed from the caller's buffer.
#[derive(Clone, Copy, Debug)]
pub struct Window<'a> {
    /// Where the pixels lie on the active area.
    pub rect: Rect,
    /// `rect.len()` calibrated values, row-major.
    pub pixels_e: &'a [Electrons],
}

impl<'a> Window<'a> {
    /// Pairs a rectangle with its pixels; `None` when the slice length does not match.
    pub fn new(rect: Rect, pixels_e: &'a [Electrons]) -> Option<Self> {
        (pixels_e.len() == rect.len()).then_some(Self { rect, pixels_e })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_window_inside_a_window() {
        let w = Rect {
            x0: 100,
            y0: 200,
            width: 15,
            height: 15,
        };
        let inner = |x0, y0, width, height| Rect {
            x0,
            y0,
            width,
            height,
        };
        assert_eq!(w.centred_within(107, 207, 11), inner(102, 202, 11, 11));
        // Near the window's corner: clipped to it, not to the frame.
        assert_eq!(w.centred_within(101, 201, 11), inner(100, 200, 7, 7));
        assert_eq!(w.centred_within(114, 214, 11), inner(109, 209, 6, 6));
        // A centre outside the window (left of it) clips to its first column.
        assert_eq!(w.centred_within(90, 207, 11), inner(100, 202, 6, 11));
    }

    #[test]
    fn clipping_at_edges() {
        let (r, c) = Rect::centred_clipped(0, 0, 5, 1024, 1024);
        assert_eq!(
            r,
            Rect {
                x0: 0,
                y0: 0,
                width: 3,
                height: 3
            }
        );
        assert!(c);
        let (r, c) = Rect::centred_clipped(1023, 10, 5, 1024, 1024);
        assert_eq!(
            r,
            Rect {
                x0: 1021,
                y0: 8,
                width: 3,
                height: 5
            }
        );
        assert!(c);
        let (r, c) = Rect::centred_clipped(100, 100, 7, 1024, 1024);
        assert_eq!(
            r,
            Rect {
                x0: 97,
                y0: 97,
                width: 7,
                height: 7
            }
        );
        assert!(!c);
        assert!(r.contains(103, 97) && !r.contains(104, 97));
    }
}
