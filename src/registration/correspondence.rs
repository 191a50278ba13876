//! Putative correspondences from feature-space nearest neighbours.

use crate::features::nearest::nearest_both_ways;
use crate::features::Fpfh;
use serde::{Deserialize, Serialize};

/// A putative match: source point `source` ↔ target point `target`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Correspondence {
    /// Index into the source cloud.
    pub source: u32,
    /// Index into the target cloud.
    pub target: u32,
}

/// How feature matches are filtered.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// Keep only mutual nearest neighbours (default true). If fewer than `min_mutual` survive, the
    /// one-way matches of both directions are used instead (as Open3D does).
    pub mutual: bool,
    /// Fewest mutual matches accepted before falling back to one-way matches (default 30).
    pub min_mutual: usize,
    /// Lowe's ratio test: keep a source match only if `d1 / d2 < ratio` (distances, not squared);
    /// `None` disables it (default).
    pub ratio: Option<f32>,
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            mutual: true,
            min_mutual: 30,
            ratio: None,
        }
    }
}

impl MatchConfig {
    /// Checks the ranges; the error names the field (`matching.…`).
    pub fn validate(&self) -> crate::Result<()> {
        if let Some(r) = self.ratio {
            crate::error::check::fraction("matching.ratio", r as f64)?;
        }
        Ok(())
    }
}

/// Matches source descriptors to target descriptors (exact nearest neighbours in descriptor space).
/// The order of the result is deterministic (by source index, then target index).
pub fn match_features(src: &[Fpfh], tgt: &[Fpfh], cfg: &MatchConfig) -> Vec<Correspondence> {
    if src.is_empty() || tgt.is_empty() {
        return Vec::new();
    }
    let (s2t, t2s) = nearest_both_ways(src, tgt);
    let ratio_ok = |i: usize| match cfg.ratio {
        None => true,
        Some(r) => {
            let n = &s2t[i];
            n.second_dist2.is_infinite() || n.dist2.sqrt() < r * n.second_dist2.sqrt()
        }
    };
    let mutual: Vec<Correspondence> = s2t
        .iter()
        .enumerate()
        .filter(|&(i, n)| t2s[n.index as usize].index as usize == i && ratio_ok(i))
        .map(|(i, n)| Correspondence {
            source: i as u32,
            target: n.index,
        })
        .collect();
    if cfg.mutual && mutual.len() >= cfg.min_mutual {
        return mutual;
    }
    let mut all: Vec<Correspondence> = s2t
        .iter()
        .enumerate()
        .filter(|&(i, _)| ratio_ok(i))
        .map(|(i, n)| Correspondence {
            source: i as u32,
            target: n.index,
        })
        .chain(t2s.iter().enumerate().map(|(j, n)| Correspondence {
            source: n.index,
            target: j as u32,
        }))
        .collect();
    all.sort_unstable_by_key(|c| (c.source, c.target));
    all.dedup();
    all
}
