//! Dense indexes over the part of a grid of patches that one frame considers: per row, the
//! span of columns it holds ([`RowWindow`], O(1) lookup) or its maximal spans ([`SpanWindow`],
//! exactly the cells within a radius of given ones), stored back to back. Storage is linear
//! in the spans, so a selection that touches only the patches in view (and a margin around
//! them) costs what it touches, not the grid's size (no per-frame hash map, no grid-sized
//! buffer).

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
    #[cfg(test)]
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

/// Exactly the cells within L1 (city-block) distance `radius` of given cells, as per-row lists
/// of maximal column spans (disjoint, not adjacent, ascending), stored back to back: unlike
/// [`RowWindow`]'s one hull per row, a row with cells far apart on both sides of a view holds
/// only their neighbourhoods. Lookup is a search among a row's spans, or O(1) amortized
/// through a cursor when the columns asked come in order ([`SpanWindow::index_up`],
/// [`SpanWindow::index_down`]).
#[derive(Debug, Clone, Default)]
pub(crate) struct SpanWindow {
    j0: usize,
    /// Row `j0 + r`'s spans are `spans[starts[r]..starts[r + 1]]`.
    starts: Vec<usize>,
    /// `(lo, hi, offset)`: first and last column (inclusive), slot of the first.
    spans: Vec<(usize, usize, usize)>,
    len: usize,
}

impl SpanWindow {
    /// The window of every cell within `radius` of one of `cells` (column, row), clipped to a
    /// grid of `nx` by `ny`, and `cells` sorted row-major (duplicates kept). Cost: `O(cells
    /// + rows x radius x spans)` and a sort of each row's cells.
    pub(crate) fn dilated(
        cells: &[(usize, usize)],
        radius: usize,
        nx: usize,
        ny: usize,
    ) -> (Self, Vec<(usize, usize)>) {
        let Some((jmin, jmax)) = cells.iter().fold(None, |acc, &(_, j)| match acc {
            None => Some((j, j)),
            Some((a, b)) => Some((j.min(a), j.max(b))),
        }) else {
            return (Self::default(), Vec::new());
        };
        // The cells bucketed by row, each row sorted by column.
        let rows_in = jmax - jmin + 1;
        let mut at = vec![0usize; rows_in + 1];
        for &(_, j) in cells {
            at[j - jmin + 1] += 1;
        }
        for r in 0..rows_in {
            at[r + 1] += at[r];
        }
        let mut fill = at.clone();
        let mut sorted = vec![(0, 0); cells.len()];
        for &(i, j) in cells {
            sorted[fill[j - jmin]] = (i, j);
            fill[j - jmin] += 1;
        }
        // Per input row, its cells' maximal runs of adjacent columns.
        let mut runs_at = Vec::with_capacity(rows_in + 1);
        let mut runs: Vec<(usize, usize)> = Vec::new();
        for r in 0..rows_in {
            let row = &mut sorted[at[r]..at[r + 1]];
            row.sort_unstable();
            let first = runs.len();
            runs_at.push(first);
            for &(i, _) in row.iter() {
                match runs[first..].last_mut() {
                    Some(last) if i <= last.1 + 1 => last.1 = last.1.max(i),
                    _ => runs.push((i, i)),
                }
            }
        }
        runs_at.push(runs.len());
        let j0 = jmin.saturating_sub(radius);
        let j1 = (jmax + radius).min(ny.saturating_sub(1));
        let mut starts = Vec::with_capacity(j1 + 2 - j0);
        let mut spans = Vec::new();
        let mut len = 0;
        let mut widened: Vec<(usize, usize)> = Vec::new();
        for j in j0..=j1 {
            starts.push(spans.len());
            widened.clear();
            let a = j.saturating_sub(radius).max(jmin);
            let b = (j + radius).min(jmax);
            for src in a..=b {
                let w = radius - src.abs_diff(j);
                let r = src - jmin;
                widened.extend(
                    runs[runs_at[r]..runs_at[r + 1]].iter().map(|&(lo, hi)| {
                        (lo.saturating_sub(w), (hi + w).min(nx.saturating_sub(1)))
                    }),
                );
            }
            widened.sort_unstable();
            let first = spans.len();
            for &(lo, hi) in &widened {
                match spans[first..].last_mut() {
                    Some((_, last_hi, _)) if lo <= *last_hi + 1 => {
                        if hi > *last_hi {
                            len += hi - *last_hi;
                            *last_hi = hi;
                        }
                    }
                    _ => {
                        spans.push((lo, hi, len));
                        len += hi - lo + 1;
                    }
                }
            }
        }
        starts.push(spans.len());
        (Self { j0, starts, spans, len }, sorted)
    }

    /// Slots in the window.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// Row `j`'s spans `(lo, hi, offset)`, ascending (empty outside the window's rows).
    #[inline]
    pub(crate) fn row(&self, j: usize) -> &[(usize, usize, usize)] {
        match j.checked_sub(self.j0) {
            Some(r) if r + 1 < self.starts.len() => &self.spans[self.starts[r]..self.starts[r + 1]],
            _ => &[],
        }
    }

    /// The rows in ascending order with their spans (rows without spans included).
    pub(crate) fn rows(
        &self,
    ) -> impl DoubleEndedIterator<Item = (usize, &[(usize, usize, usize)])> + '_ {
        self.starts.windows(2).enumerate().map(|(r, w)| (self.j0 + r, &self.spans[w[0]..w[1]]))
    }

    /// The slot of cell `(i, j)`, or `None` outside the window.
    #[cfg(test)]
    pub(crate) fn index(&self, i: usize, j: usize) -> Option<usize> {
        let row = self.row(j);
        let s = row.partition_point(|&(_, hi, _)| hi < i);
        row.get(s).filter(|&&(lo, _, _)| lo <= i).map(|&(lo, _, off)| off + i - lo)
    }

    /// The slot of `(i, j)` for columns `i` asked in ascending order within row `j`: `cursor`
    /// (start it at 0 for each row) remembers the span reached.
    #[inline]
    pub(crate) fn index_up(&self, i: usize, j: usize, cursor: &mut usize) -> Option<usize> {
        let row = self.row(j);
        while *cursor < row.len() && row[*cursor].1 < i {
            *cursor += 1;
        }
        let &(lo, _, off) = row.get(*cursor)?;
        (lo <= i).then(|| off + i - lo)
    }

    /// The slot of `(i, j)` for columns `i` asked in descending order within row `j`:
    /// `cursor` (start it at `usize::MAX` for each row) remembers the span reached.
    #[inline]
    pub(crate) fn index_down(&self, i: usize, j: usize, cursor: &mut usize) -> Option<usize> {
        let row = self.row(j);
        let mut s = (*cursor).min(row.len());
        while s > 0 && row[s - 1].0 > i {
            s -= 1;
        }
        *cursor = s;
        let &(_, hi, off) = row.get(s.checked_sub(1)?)?;
        let lo = row[s - 1].0;
        (i <= hi).then(|| off + i - lo)
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

    #[test]
    fn span_dilation_holds_exactly_the_cells_within_the_radius() {
        let (nx, ny) = (41, 23);
        // Far apart in one row (a hull would hold everything between), adjacent, duplicated.
        let cells = [(2usize, 5usize), (38, 5), (20, 11), (21, 11), (21, 11), (0, 22), (40, 0)];
        for radius in 0..6 {
            let (w, sorted) = SpanWindow::dilated(&cells, radius, nx, ny);
            let mut want = cells.to_vec();
            want.sort_unstable_by_key(|&(i, j)| (j, i));
            assert_eq!(sorted, want);
            let mut slots = vec![false; w.len()];
            let mut inside = 0;
            for j in 0..ny {
                let (mut up, mut down) = (0, usize::MAX);
                let downs: Vec<_> = (0..nx).rev().map(|i| w.index_down(i, j, &mut down)).collect();
                for i in 0..nx {
                    let near = cells.iter().any(|&(a, b)| a.abs_diff(i) + b.abs_diff(j) <= radius);
                    let k = w.index(i, j);
                    assert_eq!(k.is_some(), near, "({i}, {j}) radius {radius}");
                    assert_eq!(w.index_up(i, j, &mut up), k);
                    assert_eq!(downs[nx - 1 - i], k);
                    if let Some(k) = k {
                        assert!(!slots[k], "slot {k} used twice");
                        slots[k] = true;
                        inside += 1;
                    }
                }
                // Spans are maximal: no two touch.
                assert!(w.row(j).windows(2).all(|p| p[0].1 + 1 < p[1].0));
            }
            assert_eq!(inside, w.len());
            // Far-apart cells of one row: the window does not hold what lies between.
            assert_eq!(w.index(20, 5), None, "radius {radius}");
        }
        let (empty, sorted) = SpanWindow::dilated(&[], 3, nx, ny);
        assert_eq!(
            (empty.len(), empty.index(0, 0), empty.rows().count(), sorted.len()),
            (0, None, 0, 0)
        );
    }
}
