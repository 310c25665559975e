//! Stored motions' channels kept in memory for queries by stored id: a
//! query by id then reads no database row at all (the store's blob read
//! walks SQLite's overflow pages up to the segment, and each read is a
//! round trip to the connection's thread). Least recently used motions
//! leave first when the budget is full; a motion too large for a sixteenth
//! of the budget is never kept (its segment is read from the store).
//!
//! A motion's channels never change under its id; an entry is also keyed
//! by the motion's content hash, so an id the store gives again after a
//! delete is not served another motion's channels.

use crate::features::CHANNELS;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// The default budget (`choreo serve --channel-cache-mb`).
pub const DEFAULT_BUDGET_MB: usize = 256;

const FRAME_BYTES: usize = CHANNELS * 4;

struct Entry {
    hash: String,
    channels: Arc<Vec<[f32; CHANNELS]>>,
    used: u64,
}

#[derive(Default)]
struct Inner {
    entries: HashMap<i64, Entry>,
    bytes: usize,
    clock: u64,
    hits: u64,
    misses: u64,
}

pub struct ChannelCache {
    budget: usize,
    inner: Mutex<Inner>,
}

impl ChannelCache {
    pub fn new(budget_bytes: usize) -> ChannelCache {
        ChannelCache {
            budget: budget_bytes,
            inner: Mutex::new(Inner::default()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().expect("channel cache")
    }

    /// Whether a motion of this many frames is worth keeping whole.
    pub fn fits(&self, frames: usize) -> bool {
        frames.saturating_mul(FRAME_BYTES) <= self.budget / 16
    }

    /// The channels of motion `id` if kept (and kept for this content).
    pub fn get(&self, id: i64, hash: &str) -> Option<Arc<Vec<[f32; CHANNELS]>>> {
        let mut g = self.lock();
        g.clock += 1;
        let now = g.clock;
        let found = match g.entries.get_mut(&id) {
            Some(e) if e.hash == hash => {
                e.used = now;
                Some(e.channels.clone())
            }
            _ => None,
        };
        match found {
            Some(_) => g.hits += 1,
            None => g.misses += 1,
        }
        found
    }

    /// Keep a motion's channels, evicting the least recently used.
    pub fn put(&self, id: i64, hash: &str, channels: Arc<Vec<[f32; CHANNELS]>>) {
        let size = channels.len() * FRAME_BYTES;
        if size > self.budget / 16 {
            return;
        }
        let mut g = self.lock();
        g.clock += 1;
        let now = g.clock;
        if let Some(old) = g.entries.remove(&id) {
            g.bytes -= old.channels.len() * FRAME_BYTES;
        }
        while g.bytes + size > self.budget {
            let Some(oldest) = g
                .entries
                .iter()
                .min_by_key(|(_, e)| e.used)
                .map(|(k, _)| *k)
            else {
                break;
            };
            if let Some(e) = g.entries.remove(&oldest) {
                g.bytes -= e.channels.len() * FRAME_BYTES;
            }
        }
        g.bytes += size;
        g.entries.insert(
            id,
            Entry {
                hash: hash.to_string(),
                channels,
                used: now,
            },
        );
    }

    /// Drop a deleted motion.
    pub fn forget(&self, id: i64) {
        let mut g = self.lock();
        if let Some(e) = g.entries.remove(&id) {
            g.bytes -= e.channels.len() * FRAME_BYTES;
        }
    }

    /// (hits, misses, bytes kept) since start.
    pub fn stats(&self) -> (u64, u64, usize) {
        let g = self.lock();
        (g.hits, g.misses, g.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(frames: usize, v: f32) -> Arc<Vec<[f32; CHANNELS]>> {
        Arc::new(vec![[v; CHANNELS]; frames])
    }

    #[test]
    fn least_recently_used_leaves_first_and_hash_guards_reused_ids() {
        // Room for 3 motions of 100 frames; each is under a sixteenth.
        let c = ChannelCache::new(16 * 100 * FRAME_BYTES);
        assert!(c.fits(100) && !c.fits(101));
        for id in 0..3 {
            c.put(id, "h", motion(100, id as f32));
        }
        assert!(c.get(0, "h").is_some()); // 0 is now the most recent
        for id in 3..16 {
            c.put(id, "h", motion(100, id as f32));
        }
        // 16 × 100 frames fill the budget exactly: nothing evicted yet.
        assert_eq!(c.stats().2, 16 * 100 * FRAME_BYTES);
        c.put(16, "h", motion(100, 16.0));
        assert!(c.get(1, "h").is_none(), "1 was the least recently used");
        assert!(c.get(0, "h").is_some());
        // The same id with other content is a miss, not the old channels.
        assert!(c.get(0, "other").is_none());
        c.forget(0);
        assert!(c.get(0, "h").is_none());
        // Too large for a sixteenth of the budget: not kept.
        c.put(99, "h", motion(101, 0.0));
        assert!(c.get(99, "h").is_none());
        let (hits, misses, _) = c.stats();
        assert_eq!((hits, misses), (2, 4));
    }
}
