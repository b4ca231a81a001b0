//! A dense index over the part of a grid of patches that one frame considers: per row, the
//! span of columns it holds, stored back to back. Lookup is O(1) and storage is linear in the
//! spans, so a selection that touches only the patches in view (and a margin around them)
//! costs what it touches, not the grid's size (no per-frame hash map, no grid-sized buffer).

/// Per-row column spans over rows `j0..j0 + rows.len()`.
#[derive(Debug, Clone, Default)]
pub(crate) struct RowWindow {
    j0: usize,
    /// Per row: first column, last column (inclusive; `lo > hi` when empty), offset of the
    /// first column's slot.
    rows: Vec<(usize, usize, usize)>,
    len: usize,
}

impl RowWindow {
    /// The window holding every cell within L1 (city-block) distance `radius` of one of
    /// `cells` (column, row), clipped to a grid of `nx` by `ny`: row `j`'s span is the hull of
    /// row `j + dj`'s input span widened by `radius - |dj|`, for `|dj| <= radius`. The hull
    /// may hold a few cells farther away (never fewer). Cost: `O(cells + rows x radius)`.
    pub(crate) fn dilated(
        cells: impl IntoIterator<Item = (usize, usize)> + Clone,
        radius: usize,
        nx: usize,
        ny: usize,
    ) -> Self {
        let Some((jmin, jmax)) = cells.clone().into_iter().fold(None, |acc, (_, j)| match acc {
            None => Some((j, j)),
            Some((a, b)) => Some((j.min(a), j.max(b))),
        }) else {
            return Self::default();
        };
        // Input spans per row (lo > hi: none).
        let mut input = vec![(usize::MAX, 0usize); jmax - jmin + 1];
        for (i, j) in cells {
            let s = &mut input[j - jmin];
            s.0 = s.0.min(i);
            s.1 = s.1.max(i);
        }
        let j0 = jmin.saturating_sub(radius);
        let j1 = (jmax + radius).min(ny.saturating_sub(1));
        let mut rows = Vec::with_capacity(j1 + 1 - j0);
        let mut len = 0;
        for j in j0..=j1 {
            let (mut lo, mut hi) = (usize::MAX, 0usize);
            let a = j.saturating_sub(radius).max(jmin);
            let b = (j + radius).min(jmax);
            for src in a..=b {
                let (slo, shi) = input[src - jmin];
                if slo > shi {
                    continue;
                }
                let w = radius - src.abs_diff(j);
                lo = lo.min(slo.saturating_sub(w));
                hi = hi.max((shi + w).min(nx.saturating_sub(1)));
            }
            rows.push((lo, hi, len));
            if lo <= hi {
                len += hi - lo + 1;
            }
        }
        Self { j0, rows, len }
    }

    /// Slots in the window.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// The slot of cell `(i, j)`, or `None` outside the window.
    #[inline]
    pub(crate) fn index(&self, i: usize, j: usize) -> Option<usize> {
        let &(lo, hi, off) = self.rows.get(j.checked_sub(self.j0)?)?;
        (lo <= i && i <= hi).then(|| off + (i - lo))
    }

    /// The rows in ascending order: `(j, lo, hi, offset)`; empty rows are skipped.
    pub(crate) fn rows(
        &self,
    ) -> impl DoubleEndedIterator<Item = (usize, usize, usize, usize)> + '_ {
        self.rows
            .iter()
            .enumerate()
            .filter(|(_, s)| s.0 <= s.1)
            .map(|(k, &(lo, hi, off))| (self.j0 + k, lo, hi, off))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_holds_every_cell_within_the_radius_and_indexes_densely() {
        let (nx, ny) = (23, 17);
        let cells = [(3usize, 4usize), (10, 4), (20, 12), (0, 16)];
        for radius in 0..5 {
            let w = RowWindow::dilated(cells.iter().copied(), radius, nx, ny);
            let mut slots = vec![false; w.len()];
            for j in 0..ny {
                for i in 0..nx {
                    let near = cells.iter().any(|&(a, b)| a.abs_diff(i) + b.abs_diff(j) <= radius);
                    match w.index(i, j) {
                        Some(k) => {
                            assert!(!slots[k], "slot {k} used twice");
                            slots[k] = true;
                        }
                        None => assert!(!near, "({i}, {j}) within {radius} but outside"),
                    }
                }
            }
            assert!(slots.iter().all(|&s| s), "every slot is some cell's");
            // Outside the grid: no slot.
            assert_eq!(w.index(nx, 4), None);
            assert_eq!(w.index(3, ny + 10), None);
        }
        let empty = RowWindow::dilated(std::iter::empty(), 3, nx, ny);
        assert_eq!((empty.len(), empty.index(0, 0), empty.rows().count()), (0, None, 0));
    }
}
