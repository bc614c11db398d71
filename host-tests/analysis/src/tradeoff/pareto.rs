//! The Pareto frontier of cost against error within one scene.
//!
//! A point is on the frontier when no other point is both cheaper and more accurate: no `q`
//! with `q.cost <= p.cost` and `q.error <= p.error` and at least one of the two strictly
//! smaller. Equal points are both on it. Points with a non-finite cost or error are never on
//! it and dominate nothing. Cost: O(n^2) comparisons (n is the number of
//! methods, [`super::methods`]).

/// Which of `points` (`(cost, error)`) are on the frontier, in the same order.
pub fn frontier(points: &[(f64, f64)]) -> Vec<bool> {
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    points
        .iter()
        .map(|p| {
            finite(p)
                && !points
                    .iter()
                    .any(|q| finite(q) && q.0 <= p.0 && q.1 <= p.1 && (q.0 < p.0 || q.1 < p.1))
        })
        .collect()
}
