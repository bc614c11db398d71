//! The founding paper's star image: a Gaussian of 80 % radius `a` (eq. 5, sigma =
//! sqrt(0.31) a) integrated over each pixel (eq. 3), a product of erf differences per axis.

/// Gaussian sigma (px) of the paper's 80 % radius `a_px`.
pub fn sigma_of_a(a_px: f64) -> f64 {
    (0.31f64).sqrt() * a_px
}

/// Fraction of a star's signal that falls in the pixel centred at integer `i` along one
/// axis, for a star centred at `c` with Gaussian sigma `s`.
pub fn pixel_fraction(i: f64, c: f64, s: f64) -> f64 {
    let k = 1.0 / (s * std::f64::consts::SQRT_2);
    0.5 * (libm::erf((i + 0.5 - c) * k) - libm::erf((i - 0.5 - c) * k))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_holds_80_percent() {
        // The radius a encloses 80 % of a circular Gaussian: 1 - exp(-a^2 / (2 s^2)) = 0.8.
        let s = sigma_of_a(1.0);
        let enclosed = 1.0 - (-1.0 / (2.0 * s * s)).exp();
        assert!((enclosed - 0.8).abs() < 0.002, "{enclosed}");
        let total: f64 = (-20..=20)
            .map(|i| pixel_fraction(f64::from(i), 0.3, 1.2))
            .sum();
        assert!((total - 1.0).abs() < 1e-12);
    }
}
