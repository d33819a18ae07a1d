//! Where a [`super::LiveGestureModel`]'s streams keep their caches between
//! [`MotionModel::step_many`](crate::model::MotionModel::step_many) calls: stacked on the batch axis
//! in **cohorts**, the streams last stepped together.
//!
//! A server steps the same streams together tick after tick (real-time sessions complete their
//! tokens at steady phases). Stacking every stream's caches before each graph run and splitting them
//! after it copied all of them twice per step; a cohort keeps them stacked, so a step of the same
//! streams hands the graphs their caches as they are (moved). When the
//! set of streams changes, only the streams that join or leave the cohort are copied.
//!
//! A stream whose caches are in a cohort is *away* ([`super::LiveGestureStream`] keeps a key and a
//! flag; its own caches are empty meanwhile). Stepping it alone (its own `push_audio`, `finish`)
//! first calls it home ([`Cohorts::recall`]: its rows copied out of the cohort); dropping it drops
//! its rows ([`Cohorts::forget`]). Every cohort operation runs under the model's graphs lock, then
//! this one's.

use anyhow::{anyhow, ensure, Result};
use ndarray::Array2;

use super::caches::{Caches, StackedCaches};
use super::{LiveGestureGraphs, Stream, TokenStep};

/// The smallest cohort stepped apart from the other streams of a step ([`Cohorts::plan`]): a step
/// apart costs its graph runs' fixed part (ort: about 3.5 ms on the 2-core AMD VM of BENCHMARKS.md,
/// the one-stream chain less the per-stream cost), gathering costs copying each stream in and out
/// again (about 0.25 ms per stream of `models/default`'s 1.74 MB, buffers growing included): even
/// from about 12 streams.
pub(super) const MIN_APART: usize = 12;

/// The most streams stepped in one graph run ([`Cohorts::plan`] splits larger groups evenly). A
/// server's slots step about a quarter of its sessions each, so this binds only when a server falls
/// behind or a crowd of new sessions arrives at once: then one cohort of every session (96 on one core,
/// 2026-11-28) stepped at about 1.9 ms per session where slots of 16-20 took about 1.4 (the stacked
/// caches of 96 streams, 167 MB, are far from the core's caches), and stayed merged, since all its
/// streams were due together from then on.
pub(super) const MAX_STEP: usize = 32;

/// Caches of streams stepped together, stacked in member order.
#[derive(Debug)]
struct Cohort {
    keys: Vec<u64>,
    /// Rows of each member in the expert and fusion caches (2 with guidance, else 1).
    branch: Vec<usize>,
    caches: Caches,
    /// The last step's input caches: output buffers for the next step.
    spare: Caches,
}

impl Cohort {
    fn new(empty: &Caches) -> Self {
        Cohort {
            keys: Vec::new(),
            branch: Vec::new(),
            caches: empty.clone(),
            spare: empty.clone(),
        }
    }

    fn position(&self, key: u64) -> Option<usize> {
        self.keys.iter().position(|&k| k == key)
    }

    /// Appends a member's caches (copied; its ring caches first moved to the cohort's phase, or
    /// the cohort takes its phase when empty).
    fn push(&mut self, key: u64, branch: usize, caches: &mut Caches) -> Result<()> {
        if self.keys.is_empty() {
            self.caches.phase = caches.phase;
        } else if caches.phase != self.caches.phase {
            caches.rephase(self.caches.phase)?;
        }
        for slot in self.caches.slots() {
            let have = self.caches.slot_mut(slot);
            let add = caches.slot(slot);
            ensure!(
                have.len() == add.len(),
                "a stream with {} caches for a graph with {}",
                add.len(),
                have.len()
            );
            for (h, a) in have.iter_mut().zip(add) {
                h.append_rows(a)?;
            }
        }
        self.keys.push(key);
        self.branch.push(branch);
        Ok(())
    }

    /// (first row, rows) of member `i` in `slot`'s caches.
    fn rows_of(&self, i: usize, branched: bool) -> (usize, usize) {
        if branched {
            (self.branch[..i].iter().sum(), self.branch[i])
        } else {
            (i, 1)
        }
    }

    /// Moves member `i` to the end of `to` (its rows copied once, then removed here).
    /// Its ring caches' rows are rotated to `to`'s phase as they arrive (`to` takes this phase
    /// when empty).
    fn move_to(&mut self, i: usize, to: &mut Cohort, empty: &Caches) -> Result<()> {
        let at: usize = to.branch.iter().sum();
        if to.keys.is_empty() {
            to.caches.phase = self.caches.phase;
        }
        for slot in self.caches.slots() {
            let (start, count) = self.rows_of(i, slot.branched());
            let have = to.caches.slot_mut(slot);
            for (h, src) in have.iter_mut().zip(self.caches.slot(slot)) {
                h.append_rows_of(src, start, count)?;
            }
        }
        if to.caches.phase != self.caches.phase {
            to.caches
                .rephase_rows(at, self.branch[i], self.caches.phase)?;
        }
        to.keys.push(self.keys[i]);
        to.branch.push(self.branch[i]);
        self.remove(i, false, empty)?;
        Ok(())
    }

    /// Removes member `i`, returning a copy of its caches when `keep` (moving the last member into
    /// its place when both have as many rows, else shifting the later ones).
    fn remove(&mut self, i: usize, keep: bool, empty: &Caches) -> Result<Option<Caches>> {
        let last = self.keys.len() - 1;
        let swap = i != last && self.branch[last] == self.branch[i];
        let (branch_start, branch) = self.rows_of(i, true);
        let out = self.caches.remove_stream_rows(
            (branch_start, branch, i),
            swap,
            keep.then_some(empty),
        )?;
        if swap {
            self.keys.swap_remove(i);
            self.branch.swap_remove(i);
        } else {
            self.keys.remove(i);
            self.branch.remove(i);
        }
        Ok(out)
    }
}

/// The cohorts of one model's streams (see the module docs).
#[derive(Debug)]
pub(super) struct Cohorts {
    groups: Vec<Cohort>,
    /// Every cache tensor with zero rows (the layout of a cohort).
    empty: Caches,
    next_key: u64,
    /// Streams whose caches were copied so far: into a cohort (from home or another cohort), or out
    /// of one into a cohort of their own (left behind by their step-mates).
    moved: u64,
}

/// A stream of a [`Cohorts::step`]: its key and the stream (its caches are in a cohort when `away`).
pub(super) struct Member<'a> {
    pub(super) key: u64,
    pub(super) away: &'a mut bool,
    pub(super) stream: &'a mut Stream,
}

impl Cohorts {
    pub(super) fn new(empty: Caches) -> Self {
        Cohorts {
            groups: Vec::new(),
            empty,
            next_key: 0,
            moved: 0,
        }
    }

    /// Streams whose caches were copied between cohorts so far: each stream stepped in other
    /// company than last time (a new stream, one whose step-mates changed) counts once, and so does
    /// each stream left behind by its step-mates.
    pub(super) fn moved(&self) -> u64 {
        self.moved
    }

    /// Splits the streams of one token step (`keys`) into groups stepped apart (indices into
    /// `keys`): each cohort of at least [`MIN_APART`] streams whose streams are all in `keys` is a
    /// group of its own (stepped as it is, nothing copied), and the other streams one more group
    /// (gathered by [`Cohorts::step`]), or part of the largest group when they are fewer than
    /// [`MIN_APART`]. One group (all of `keys`) when nothing is apart. A group of more than
    /// [`MAX_STEP`] streams is split evenly into groups of at most that many.
    ///
    /// A server behind its tick grid steps the sessions of several slots at once; gathering them in
    /// one cohort copied every one of them (and again when their slots step apart next time):
    /// measured at 72 sessions on one core, steps of 72 sessions took 150-180 ms where steps of 18
    /// took 25 ms, and the server never caught up.
    pub(super) fn plan(&self, keys: &[u64]) -> Vec<Vec<usize>> {
        let groups = self.plan_apart(keys);
        if groups.iter().all(|g| g.len() <= MAX_STEP) {
            return groups;
        }
        let mut out = Vec::new();
        for g in groups {
            let parts = g.len().div_ceil(MAX_STEP);
            let size = g.len().div_ceil(parts);
            out.extend(g.chunks(size).map(<[usize]>::to_vec));
        }
        out
    }

    /// [`Cohorts::plan`] before groups are cut to [`MAX_STEP`].
    fn plan_apart(&self, keys: &[u64]) -> Vec<Vec<usize>> {
        let n = keys.len();
        if n < 2 * MIN_APART {
            return vec![(0..n).collect()];
        }
        let pos: std::collections::HashMap<u64, usize> =
            keys.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        let mut apart: Vec<Vec<usize>> = Vec::new();
        let mut taken = vec![false; n];
        for c in &self.groups {
            if c.keys.len() >= MIN_APART && c.keys.iter().all(|k| pos.contains_key(k)) {
                let g: Vec<usize> = c.keys.iter().map(|k| pos[k]).collect();
                for &i in &g {
                    taken[i] = true;
                }
                apart.push(g);
            }
        }
        let rest: Vec<usize> = (0..n).filter(|&i| !taken[i]).collect();
        if rest.is_empty() {
            return apart;
        }
        if rest.len() >= MIN_APART {
            apart.push(rest);
            return apart;
        }
        match apart.iter_mut().max_by_key(|g| g.len()) {
            Some(largest) => largest.extend(rest),
            None => apart.push(rest),
        }
        apart
    }

    /// A key for a new stream.
    pub(super) fn key(&mut self) -> u64 {
        self.next_key += 1;
        self.next_key
    }

    fn find(&self, key: u64) -> Option<(usize, usize)> {
        self.groups
            .iter()
            .enumerate()
            .find_map(|(g, c)| c.position(key).map(|i| (g, i)))
    }

    /// Takes `key`'s caches out of its cohort (a copy when `keep`); drops emptied cohorts.
    fn take(&mut self, key: u64, keep: bool) -> Result<Option<Caches>> {
        let (g, i) = self
            .find(key)
            .ok_or_else(|| anyhow!("stream {key}: its caches are in no cohort"))?;
        let out = self.groups[g].remove(i, keep, &self.empty)?;
        if self.groups[g].keys.is_empty() {
            self.groups.swap_remove(g);
        }
        Ok(out)
    }

    /// Brings an away stream's caches home (no-op for a stream at home).
    pub(super) fn recall(&mut self, key: u64, away: &mut bool, stream: &mut Stream) -> Result<()> {
        if !*away {
            return Ok(());
        }
        let caches = self.take(key, true)?;
        *away = false;
        match caches {
            Some(c) => stream.caches = c,
            None => stream.poisoned = true,
        }
        Ok(())
    }

    /// Drops a stream's caches from its cohort (the stream is dropped or reset).
    pub(super) fn forget(&mut self, key: u64, away: &mut bool) {
        if std::mem::take(away) {
            let _ = self.take(key, false);
        }
    }

    /// One token step of `members` (`mels[i]` for `members[i]`; checked by the caller, streams not
    /// poisoned): their caches are gathered in one cohort (only those not already in it are moved),
    /// which the graphs step in place. Returns the token steps in `members` order. On error the
    /// members are poisoned and their cohort dropped.
    pub(super) fn step(
        &mut self,
        graphs: &LiveGestureGraphs,
        members: &mut [Member<'_>],
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        let r = self.gather(members).and_then(|g| {
            let c = &mut self.groups[g];
            // the members in cohort order
            let mut order: Vec<usize> = Vec::with_capacity(c.keys.len());
            for k in &c.keys {
                order.push(
                    members
                        .iter()
                        .position(|m| m.key == *k)
                        .ok_or_else(|| anyhow!("stream {k} is in the cohort but not stepped"))?,
                );
            }
            let block: Vec<Array2<f32>> = order.iter().map(|&i| mels[i].clone()).collect();
            let n_members = members.len();
            let mut slots: Vec<Option<&mut Member<'_>>> = members.iter_mut().map(Some).collect();
            let mut states = Vec::with_capacity(order.len());
            for &i in &order {
                let m = slots[i]
                    .take()
                    .ok_or_else(|| anyhow!("a stream is twice in one step"))?;
                states.push(&mut m.stream.state);
            }
            let mut store = StackedCaches {
                cur: &mut c.caches,
                spare: &mut c.spare,
            };
            let steps = graphs.step_inner(&mut states, &mut store, &block)?;
            let mut out: Vec<Option<TokenStep>> = (0..n_members).map(|_| None).collect();
            for (&i, s) in order.iter().zip(steps) {
                out[i] = Some(s);
            }
            out.into_iter()
                .map(|s| s.ok_or_else(|| anyhow!("a stream got no token step")))
                .collect()
        });
        if r.is_err() {
            // the cohort's caches may be partial: its members (these streams) start over after reset
            for m in members.iter_mut() {
                if *m.away {
                    self.forget(m.key, m.away);
                }
                m.stream.poisoned = true;
            }
        }
        r
    }

    /// Makes one cohort hold exactly `members`' caches; returns its index.
    fn gather(&mut self, members: &mut [Member<'_>]) -> Result<usize> {
        let is_member = |k: u64| members.iter().any(|m| m.key == k);
        // the cohort that already holds the most of them
        let best = self
            .groups
            .iter()
            .enumerate()
            .map(|(g, c)| (c.keys.iter().filter(|&&k| is_member(k)).count(), g))
            .max();
        // keeping that cohort moves its other streams out and the missing ones in; a new cohort
        // moves every one of them in: the cheaper of the two
        let keep = |n: usize, g: usize| self.groups[g].keys.len() - n + (members.len() - n);
        let g = match best {
            Some((n, g)) if n > 0 && keep(n, g) <= members.len() => {
                // its other streams move to a cohort of their own
                // (key, branch rows) of each
                let others: Vec<(u64, usize)> = self.groups[g]
                    .keys
                    .iter()
                    .copied()
                    .zip(self.groups[g].branch.iter().copied())
                    .filter(|&(k, _)| !is_member(k))
                    .collect();
                if !others.is_empty() {
                    let mut rest = Cohort::new(&self.empty);
                    let branch_rows = others.iter().map(|&(_, b)| b).sum();
                    rest.caches.reserve(others.len(), branch_rows);
                    for (k, _) in others {
                        let c = &mut self.groups[g];
                        let i = c.position(k).ok_or_else(|| anyhow!("lost stream {k}"))?;
                        c.move_to(i, &mut rest, &self.empty)?;
                        self.moved += 1;
                    }
                    self.groups.push(rest);
                }
                g
            }
            _ => {
                self.groups.push(Cohort::new(&self.empty));
                self.groups.len() - 1
            }
        };
        // the streams not in it yet join: from home (their own caches), or from another cohort
        let mut target = std::mem::replace(&mut self.groups[g], Cohort::new(&self.empty));
        // room for the joining streams at once (growing the buffers stream by stream copies them)
        let joining: Vec<usize> = members
            .iter()
            .filter(|m| target.position(m.key).is_none())
            .map(|m| m.stream.state.branch_rows())
            .collect();
        target.caches.reserve(joining.len(), joining.iter().sum());
        let r = (|| -> Result<()> {
            for m in members.iter_mut() {
                if target.position(m.key).is_some() {
                    continue;
                }
                self.moved += 1;
                let branch = m.stream.state.branch_rows();
                if *m.away {
                    let (from, i) = self
                        .find(m.key)
                        .ok_or_else(|| anyhow!("stream {}: its caches are in no cohort", m.key))?;
                    self.groups[from].move_to(i, &mut target, &self.empty)?;
                    if self.groups[from].keys.is_empty() {
                        self.groups.swap_remove(from);
                    }
                } else {
                    target.push(m.key, branch, &mut m.stream.caches)?;
                    m.stream.caches = empty_slots(&self.empty);
                    *m.away = true;
                }
            }
            Ok(())
        })();
        // `take` may have dropped emptied cohorts: put the target back where it is found again
        let g = match self.groups.iter().position(|c| c.keys.is_empty()) {
            Some(i) => {
                self.groups[i] = target;
                i
            }
            None => {
                self.groups.push(target);
                self.groups.len() - 1
            }
        };
        r.map(|()| g)
    }
}

/// `template`'s slots without tensors: an away stream's own caches.
fn empty_slots(template: &Caches) -> Caches {
    Caches {
        audio_encoder: Vec::new(),
        experts: vec![Vec::new(); template.experts.len()],
        fusion: Vec::new(),
        decoders: vec![Vec::new(); template.decoders.len()],
        phase: 0,
        ring: template.ring.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cohorts(groups: &[std::ops::RangeInclusive<u64>]) -> Cohorts {
        let empty = empty_slots(&Caches {
            audio_encoder: Vec::new(),
            experts: Vec::new(),
            fusion: Vec::new(),
            decoders: Vec::new(),
            phase: 0,
            ring: Default::default(),
        });
        let mut c = Cohorts::new(empty);
        for keys in groups {
            let mut g = Cohort::new(&c.empty);
            g.keys = keys.clone().collect();
            g.branch = vec![2; g.keys.len()];
            c.groups.push(g);
        }
        c
    }

    /// The keys of each group of `plan(keys)`.
    fn plan(c: &Cohorts, keys: &[u64]) -> Vec<Vec<u64>> {
        c.plan(keys)
            .into_iter()
            .map(|g| g.into_iter().map(|i| keys[i]).collect())
            .collect()
    }

    #[test]
    fn whole_cohorts_step_apart_and_stragglers_join_the_largest() {
        assert_eq!(MIN_APART, 12);
        let c = cohorts(&[1..=12, 13..=26, 27..=29]);
        let a: Vec<u64> = (1..=12).collect();
        let b: Vec<u64> = (13..=26).collect();
        let ab: Vec<u64> = a.iter().chain(&b).copied().collect();
        // two whole cohorts: apart, each in its cohort's order
        assert_eq!(plan(&c, &ab), vec![a.clone(), b.clone()]);
        // and a straggler of a third (or a whole small cohort): with the largest
        let mut with = ab.clone();
        with.push(28);
        let mut b28 = b.clone();
        b28.push(28);
        assert_eq!(plan(&c, &with), vec![a.clone(), b28]);
        let mut abc = ab.clone();
        abc.extend(27..=29);
        let mut bc = b.clone();
        bc.extend(27..=29);
        assert_eq!(plan(&c, &abc), vec![a.clone(), bc]);
        // a cohort not all due is gathered with the rest: apart when they are many
        let mut partial = a.clone();
        partial.extend(13..=25);
        assert_eq!(plan(&c, &partial), vec![a.clone(), (13..=25).collect()]);
        // fewer than two cohorts' worth: one group
        assert_eq!(plan(&c, &a), vec![a.clone()]);
        // many streams of no cohort (new sessions): one group
        let fresh: Vec<u64> = (100..130).collect();
        assert_eq!(plan(&c, &fresh), vec![fresh.clone()]);
        // a whole cohort and as many new streams: apart
        let mut mixed = fresh[..12].to_vec();
        mixed.extend(&a);
        assert_eq!(plan(&c, &mixed), vec![a.clone(), fresh[..12].to_vec()]);
    }

    #[test]
    fn no_step_runs_more_than_max_step_streams() {
        assert_eq!(MAX_STEP, 32);
        let c = cohorts(&[1..=40]);
        // a crowd of 86 new streams: three steps of 29, 29 and 28
        let fresh: Vec<u64> = (100..186).collect();
        let p = plan(&c, &fresh);
        assert_eq!(p.iter().map(Vec::len).collect::<Vec<_>>(), vec![29, 29, 28]);
        assert_eq!(p.concat(), fresh);
        // a whole cohort of 40 (merged earlier): two steps of 20
        let all: Vec<u64> = (1..=40).collect();
        assert_eq!(
            plan(&c, &all),
            vec![(1..=20).collect::<Vec<_>>(), (21..=40).collect()]
        );
        // 32 stay one step
        let some: Vec<u64> = (100..132).collect();
        assert_eq!(plan(&c, &some), vec![some.clone()]);
    }
}
