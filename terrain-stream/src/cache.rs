//! The block cache: resident levels per block under a byte budget, unloaded level by level
//! (finest first) in the priority order the scheduler gives, never below what it protects.

use std::sync::Arc;

use terrain_core::hash::IdMap;

use crate::format::{BlockId, Header};
use crate::store::BlockLevels;
use crate::workers::RequestFlags;

/// One block's resident levels and loading state.
#[derive(Debug, Clone)]
pub(crate) struct CachedBlock {
    /// The resident levels.
    pub(crate) levels: BlockLevels,
    /// The last level of the request in flight for this block, if any.
    pub(crate) requested_to: Option<u8>,
    /// That request's flags: cancelled when the block leaves the scheduling region, raised
    /// when the view needs it sooner than it was asked.
    pub(crate) flags: Option<Arc<RequestFlags>>,
    /// After a fault, the frame from which loading may be tried again.
    pub(crate) retry_at_frame: u64,
}

/// Resident block levels with a byte budget (decoded bytes, 4 per sample).
#[derive(Debug)]
pub(crate) struct Cache {
    budget: u64,
    resident: u64,
    blocks: IdMap<BlockId, CachedBlock>,
}

impl Cache {
    /// An empty cache with a budget in bytes.
    pub(crate) fn new(budget: u64) -> Self {
        Self { budget, resident: 0, blocks: IdMap::default() }
    }

    /// The budget in bytes.
    pub(crate) fn budget(&self) -> u64 {
        self.budget
    }

    /// A new budget in bytes: what is above it is unloaded at the next eviction.
    pub(crate) fn set_budget(&mut self, budget: u64) {
        self.budget = budget;
    }

    /// Bytes resident.
    pub(crate) fn resident_bytes(&self) -> u64 {
        self.resident
    }

    /// A block's state, if the cache knows it.
    pub(crate) fn get(&self, id: BlockId) -> Option<&CachedBlock> {
        self.blocks.get(&id)
    }

    /// Number of resident levels of a block.
    pub(crate) fn resident_levels(&self, id: BlockId) -> usize {
        self.blocks.get(&id).map_or(0, |b| b.levels.count())
    }

    /// A block's state, created empty if needed.
    pub(crate) fn entry(&mut self, id: BlockId, header: &Header) -> &mut CachedBlock {
        self.blocks.entry(id).or_insert_with(|| CachedBlock {
            levels: BlockLevels::new(header),
            requested_to: None,
            flags: None,
            retry_at_frame: 0,
        })
    }

    /// Appends `level` to a block if it is the next one; returns the bytes added.
    pub(crate) fn push_level(
        &mut self,
        id: BlockId,
        header: &Header,
        level: u8,
        samples: Arc<[i32]>,
    ) -> Option<u64> {
        let b = self.entry(id, header);
        if b.levels.count() != level as usize {
            return None;
        }
        let bytes = samples.len() as u64 * Header::SAMPLE_BYTES;
        b.levels.push(samples).then(|| {
            self.resident += bytes;
            bytes
        })
    }

    /// Unloads finest levels while over budget, visiting `order` (lowest priority first) and
    /// keeping at least `keep` levels of each listed block. Returns the levels unloaded.
    pub(crate) fn evict(&mut self, order: &[(BlockId, usize)]) -> usize {
        let mut evicted = 0;
        for &(id, keep) in order {
            if self.resident <= self.budget {
                break;
            }
            if let Some(b) = self.blocks.get_mut(&id) {
                while self.resident > self.budget && b.levels.count() > keep {
                    self.resident -= b.levels.pop();
                    evicted += 1;
                }
            }
        }
        evicted
    }

    /// Blocks known to the cache, in the map's order (the same from run to run: its hasher
    /// has no random state; the callers sort or collect into sets).
    pub(crate) fn blocks(&self) -> impl Iterator<Item = (&BlockId, &CachedBlock)> {
        self.blocks.iter()
    }

    /// Forgets blocks with no resident level and nothing in flight.
    pub(crate) fn prune(&mut self) {
        self.blocks.retain(|_, b| {
            b.levels.count() > 0 || b.requested_to.is_some() || b.retry_at_frame > 0
        });
    }
}
