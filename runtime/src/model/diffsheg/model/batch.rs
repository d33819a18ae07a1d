//! DiffSHEG's batch step ([`MotionModel::step_many`](crate::model::MotionModel::step_many)): the
//! windows due in several streams run together.
//!
//! Every job's audio is buffered first ([`FoppasStream::accept`]); then, round by round, each stream
//! with a due window ([`FoppasStream::next_window`]) begins it, and the windows of one length share
//! their graph calls: one `speech_encoder` call for all of them, then one `denoiser` call per sampler
//! step with every stream's rows on the batch axis (two rows for a stream with guidance, cond 1 then
//! cond 0; streams may differ in guidance, speaker, DDIM steps and jumps: a stream whose window is
//! complete leaves the call). Jobs that end their stream then begin the end
//! ([`FoppasStream::begin_finish`]) and their last windows run the same way. The sampler arithmetic is
//! each stream's own ([`crate::model::diffsheg::foppas::WindowSampler`]), so a stream's frames are those it gets stepped alone, up to
//! the backend's rounding for another batch size.
//!
//! Streams recording their windows (parity tools) and streams of another model step on their own.

use std::collections::BTreeMap;
use std::sync::Arc;

use anyhow::{anyhow, Result};

use super::{DiffshegModel, DiffshegStream};
use crate::model::diffsheg::foppas::{guided_eps, MOTION_DIM};
use crate::model::diffsheg::graphs::DiffshegGraphs;
use crate::model::diffsheg::stream::{Emitted, WindowStart};
use crate::model::StreamJob;
use crate::output::Frame;

/// One stream of the step.
struct Member<'a> {
    job: usize,
    stream: &'a mut DiffshegStream,
    /// Frames covering the input, when the job ends the stream.
    end: Option<usize>,
    emitted: Vec<Emitted>,
    failed: Option<String>,
}

pub(super) fn step_many(
    model: &DiffshegModel,
    jobs: &mut [StreamJob<'_>],
) -> Vec<Result<Vec<Frame>>> {
    let mut results: Vec<Option<Result<Vec<Frame>>>> = jobs.iter().map(|_| None).collect();
    let mut members: Vec<Member<'_>> = Vec::new();
    for (i, job) in jobs.iter_mut().enumerate() {
        let ours = job
            .stream
            .as_any_mut()
            .downcast_mut::<DiffshegStream>()
            .is_some_and(|s| Arc::ptr_eq(&s.graphs, &model.graphs) && !s.inner.is_recording());
        if !ours {
            results[i] = Some(job.run_alone());
            continue;
        }
        let (audio, end) = (job.audio, job.end);
        let Some(s) = job.stream.as_any_mut().downcast_mut::<DiffshegStream>() else {
            continue;
        };
        let accepted = if s.poisoned {
            Err(anyhow!(
                "the stream failed earlier; reset it before pushing more audio"
            ))
        } else {
            s.inner.accept(audio)
        };
        match accepted {
            Ok(()) => members.push(Member {
                job: i,
                stream: s,
                end: None,
                emitted: Vec::new(),
                failed: None,
            }),
            Err(e) => results[i] = Some(Err(e)),
        }
        if let (Some(end), Some(m)) = (end, members.last_mut().filter(|m| m.job == i)) {
            // the span is checked once the audio is in (as `finish` does after `push_audio`)
            match m.stream.frames_covering(end) {
                Ok(t) => m.end = Some(t),
                Err(e) => m.failed = Some(format!("{e:#}")),
            }
        }
    }
    if !members.is_empty() {
        let g: &DiffshegGraphs = &model.graphs;
        // the windows due by audio, then the ends and their last windows
        run_due_windows(g, &mut members);
        for m in members.iter_mut().filter(|m| m.failed.is_none()) {
            if let Some(t) = m.end {
                if m.stream.inner.is_finished() {
                    continue;
                }
                match m.stream.inner.begin_finish(t) {
                    Ok(Some(e)) => m.emitted.push(e),
                    Ok(None) => {}
                    Err(e) => m.failed = Some(format!("{e:#}")),
                }
            }
        }
        run_due_windows(g, &mut members);
    }
    for m in members {
        results[m.job] = Some(match m.failed {
            Some(e) => {
                m.stream.poisoned = true;
                Err(anyhow!(e))
            }
            None => Ok(m
                .emitted
                .iter()
                .flat_map(|e| m.stream.shared.frames(e))
                .collect()),
        });
    }
    results
        .into_iter()
        .map(|r| r.unwrap_or_else(|| Err(anyhow!("the stream was not stepped"))))
        .collect()
}

/// Fails every stream of a group (a shared graph call failed).
fn fail_all(members: &mut [Member<'_>], started: &[(usize, WindowStart)], msg: String) {
    for (k, _) in started {
        members[*k].failed = Some(msg.clone());
    }
}

/// Runs rounds of due windows until no stream has one.
fn run_due_windows(g: &DiffshegGraphs, members: &mut [Member<'_>]) {
    loop {
        let mut groups: BTreeMap<usize, Vec<(usize, bool)>> = BTreeMap::new();
        for (k, m) in members.iter().enumerate() {
            if m.failed.is_some() {
                continue;
            }
            if let Some((n, last)) = m.stream.inner.next_window() {
                groups.entry(n).or_default().push((k, last));
            }
        }
        if groups.is_empty() {
            return;
        }
        for (n, group) in groups {
            run_group(g, members, n, &group);
        }
    }
}

/// One window of `n` frames in each of `group`'s streams, sharing every graph call.
fn run_group(g: &DiffshegGraphs, members: &mut [Member<'_>], n: usize, group: &[(usize, bool)]) {
    let d = MOTION_DIM;
    let mut started: Vec<(usize, WindowStart)> = Vec::new();
    for &(k, last) in group {
        match members[k].stream.inner.start_window(n, last) {
            Ok(w) => started.push((k, w)),
            Err(e) => members[k].failed = Some(format!("{e:#}")),
        }
    }
    if started.is_empty() {
        return;
    }
    let frames: Vec<usize> = started.iter().map(|(_, w)| w.start).collect();
    let mel: Vec<f32> = started
        .iter()
        .flat_map(|(_, w)| w.mel.iter().copied())
        .collect();
    let audio = match g.encode_batch(mel, started.len(), n) {
        Ok(a) => a,
        Err(e) => {
            let msg = format!("windows at frames {frames:?}: speech_encoder: {e:#}");
            return fail_all(members, &started, msg);
        }
    };
    let per = n * g.audio_dim;
    let audios: Vec<&[f32]> = audio.chunks_exact(per).collect();
    let mut samplers = Vec::with_capacity(started.len());
    for (k, w) in &started {
        match members[*k].stream.inner.sampler(w) {
            Ok(s) => samplers.push(s),
            Err(e) => return fail_all(members, &started, format!("{e:#}")),
        }
    }
    loop {
        let active: Vec<usize> = (0..samplers.len())
            .filter(|&j| samplers[j].next_call().is_some())
            .collect();
        if active.is_empty() {
            break;
        }
        let (mut xs, mut ts, mut au, mut sp, mut conds) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for &j in &active {
            let inner = &members[started[j].0].stream.inner;
            let call = samplers[j]
                .next_call()
                .expect("an active sampler has a call");
            for cond in &[1.0f32, 0.0][..inner.options().rows()] {
                xs.extend_from_slice(call.x);
                ts.push(call.t);
                au.extend_from_slice(audios[j]);
                sp.push(inner.speaker());
                conds.push(*cond);
            }
        }
        let eps = match g.denoise_batch(xs, ts, au, sp, conds, n) {
            Ok(e) => e,
            Err(e) => {
                let msg = format!("windows at frames {frames:?}: denoiser: {e:#}");
                return fail_all(members, &started, msg);
            }
        };
        let mut rest = &eps[..];
        for &j in &active {
            let inner = &members[started[j].0].stream.inner;
            let rows = inner.options().rows();
            let (mine, tail) = rest.split_at(rows * n * d);
            rest = tail;
            let (cr, ur) = mine.split_at(n * d);
            let e = guided_eps(cr, (rows == 2).then_some(ur), inner.options().guidance);
            if let Err(e) = samplers[j].feed(&e) {
                return fail_all(members, &started, format!("{e:#}"));
            }
        }
    }
    for (((k, w), sampler), audio) in started.into_iter().zip(samplers).zip(audios) {
        match sampler.finish() {
            Ok((x0, noise)) => {
                let e = members[k]
                    .stream
                    .inner
                    .complete_window(w, audio.to_vec(), x0, noise, None);
                members[k].emitted.push(e);
            }
            Err(e) => members[k].failed = Some(format!("{e:#}")),
        }
    }
}
