//! The DSS paper's strip triangulation (Zhang 2019, section 3.2.3, Algorithm 1), and the
//! sequential triangulation it replaces (its Fig. 8b), kept for the thin-triangle statistics.
//!
//! Algorithm 1: "for each side, for each two adjacent vertices `a_i a_(i+1)`, compute the
//! perpendicular bisector `l` of the segment, find the vertex `b_j` nearest `l` on the other
//! side, make triangle `a_i a_(i+1) b_j`". Both sides lie on parallel lines, so the distance
//! of `b_j` to `l` is `|y(b_j) - m_i|`, with `y` the position along the strip and `m_i` the
//! segment's midpoint. Taken literally, per segment, the rule can give two triangles that
//! overlap when the nearest vertex is ambiguous (equal distances); we run it as the
//! equivalent *merge*: walk both sides at once and always close the segment, of either side,
//! whose midpoint comes first. The apex it gets is the other side's current vertex, which is
//! exactly the vertex nearest the bisector (it lies between the other side's previous and next
//! segment midpoints, so it is nearer `m_i` than either neighbour), and ties go to the low side
//! first, so every pair of triangles shares an edge and the strip is covered once: `n_a - 1 +
//! n_b - 1` triangles, each with one segment on one side and its apex on the other.

/// Triangles of a strip between a low side at positions `low` and a high side at positions
/// `high` along it (both ascending, starting together and ending together): each is
/// `[(high side?, index), ...]` in the order base start, base end, apex.
pub fn bisector_triangles(low: &[f64], high: &[f64]) -> Vec<[(bool, u32); 3]> {
    let mut out = Vec::with_capacity((low.len() + high.len()).saturating_sub(2));
    for_each_bisector_triangle(low, high, |t| out.push(t));
    out
}

/// [`bisector_triangles`], each handed to `emit` in turn instead of collected.
pub fn for_each_bisector_triangle(low: &[f64], high: &[f64], emit: impl FnMut([(bool, u32); 3])) {
    // Ties (equal midpoints) go to the low side: the same rule from both sides.
    walk(low.len(), high.len(), |i, j| low[i] + low[i + 1] <= high[j] + high[j + 1], emit)
}

/// The sequential triangulation of the paper's Fig. 8b: advance the side that is behind *by
/// index fraction* (`i / (n_a - 1)` against `j / (n_b - 1)`), blind to positions.
pub fn sequential_triangles(low: &[f64], high: &[f64]) -> Vec<[(bool, u32); 3]> {
    let (na, nb) = (low.len().max(2) - 1, high.len().max(2) - 1);
    let mut out = Vec::with_capacity((low.len() + high.len()).saturating_sub(2));
    walk(low.len(), high.len(), |i, j| i * nb <= j * na, |t| out.push(t));
    out
}

/// The walk both triangulations share: `low_first(i, j)` says whether the low side's segment
/// `i` closes before the high side's segment `j`; each triangle goes to `emit`.
fn walk(
    na: usize,
    nb: usize,
    low_first: impl Fn(usize, usize) -> bool,
    mut emit: impl FnMut([(bool, u32); 3]),
) {
    if na == 0 || nb == 0 {
        return;
    }
    let (mut i, mut j) = (0usize, 0usize);
    while i + 1 < na || j + 1 < nb {
        let take_low = j + 1 >= nb || (i + 1 < na && low_first(i, j));
        if take_low {
            emit([(false, i as u32), (false, i as u32 + 1), (true, j as u32)]);
            i += 1;
        } else {
            emit([(true, j as u32), (true, j as u32 + 1), (false, i as u32)]);
            j += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bisector_rule_picks_the_nearest_vertex_and_covers_once() {
        // Low side: 0, 1, 2, ..., 8; high side: 0, 4, 8 (a coarse neighbour).
        let low: Vec<f64> = (0..=8).map(f64::from).collect();
        let high = [0.0, 4.0, 8.0];
        let t = bisector_triangles(&low, &high);
        assert_eq!(t.len(), 8 + 2);
        for tri in &t {
            let pos = |(hi, k): (bool, u32)| if hi { high[k as usize] } else { low[k as usize] };
            let (a, b, apex) = (pos(tri[0]), pos(tri[1]), pos(tri[2]));
            let m = 0.5 * (a + b);
            let other: &[f64] = if tri[2].0 { &high } else { &low };
            let nearest = other.iter().map(|&y| (y - m).abs()).fold(f64::INFINITY, f64::min);
            assert_eq!((apex - m).abs(), nearest, "{tri:?}");
        }
        // Every segment of both sides is the base of exactly one triangle.
        let bases = |hi: bool| t.iter().filter(|tri| tri[0].0 == hi).count();
        assert_eq!((bases(false), bases(true)), (8, 2));
    }
}
