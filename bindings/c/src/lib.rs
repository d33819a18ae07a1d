//! The LiveGesture runtime's C API (docs/c.md); `include/livegesture.h` is generated from this file
//! by cbindgen.
//!
//! A thin door onto the library API: [`livegesture::generate::open_model`] loads a bundle,
//! [`livegesture::generate::PcmStream`] is a stream fed with PCM at any rate, and
//! [`livegesture::generate::generate_wav`] is the whole-input path of `livegesture generate`.
//!
//! Rules of every entry point: it returns an [`LgStatus`] (`LG_STATUS_OK` = 0); on failure the
//! message, as the CLI prints it, is kept for [`lg_last_error`] (per thread); no panic crosses the
//! boundary (each call runs inside [`std::panic::catch_unwind`] and reports `LG_STATUS_PANIC`); a
//! NULL handle or pointer is refused with `LG_STATUS_INPUT`, never dereferenced.
#![allow(clippy::missing_safety_doc)] // the safety rules are in the header's docs (docs/c.md)

use std::cell::RefCell;
use std::collections::VecDeque;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::ptr;
use std::sync::{Arc, OnceLock};

use anyhow::{anyhow, Result};

use livegesture::backend::{BackendKind, BackendOptions};
use livegesture::generate::{self, ErrorKind, InputError, PcmStream};
use livegesture::model::GraphForm;
use livegesture::model::{MotionModel, StreamOptions};
use livegesture::output::Frame;

/// Axis-angle pose values per frame (55 SMPL-X joints x 3).
pub const LG_POSE_DIM: usize = 165;
/// Root translation values per frame (metres, Y up).
pub const LG_TRANS_DIM: usize = 3;
/// Expression coefficients per frame.
pub const LG_EXPR_DIM: usize = 100;
/// Motion frames per second.
pub const LG_FPS: u32 = 30;
/// ARKit blendshape weights per frame of the face channel (docs/face.md).
pub const LG_ARKIT_DIM: usize = 52;
/// Viseme probabilities per frame of the face channel.
pub const LG_VISEME_DIM: usize = 15;

/// One frame's face channel (docs/face.md): ARKit weights in [0, 1] (names: `lg_arkit_name`) and
/// viseme probabilities summing to 1 (names: `lg_viseme_name`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LgFace {
    /// ARKit blendshape weights, Apple's order (`eyeBlinkLeft` ... `tongueOut`).
    pub arkit: [f32; LG_ARKIT_DIM],
    /// Viseme probabilities: `sil, PP, FF, TH, DD, kk, CH, SS, nn, RR, aa, E, ih, oh, ou`.
    pub visemes: [f32; LG_VISEME_DIM],
}

/// The result of every call. On anything but `LG_STATUS_OK`, `lg_last_error()` says what went wrong.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LgStatus {
    /// Success.
    Ok = 0,
    /// A file or folder that is not there (WAV file, bundle, a graph file of the bundle).
    NotFound = 1,
    /// Another failure reading a file.
    Io = 2,
    /// Bad input: audio (not a WAV file, NaN samples, ...), bundle contents, options, NULL pointers,
    /// a stream used out of turn.
    Input = 3,
    /// A failure of the runtime itself (a backend error).
    Runtime = 4,
    /// An internal error (a panic, caught); a stream it happened in refuses work until reset.
    Panic = 5,
}

/// A loaded model bundle on one backend (opaque). Thread-safe: streams may be made from any thread.
pub struct LgModel {
    inner: Arc<dyn MotionModel>,
}

/// One stream's state and the frames waiting to be read (opaque). Use one stream from one thread at
/// a time (it may move between threads).
pub struct LgStream {
    model: Arc<dyn MotionModel>,
    opts: StreamOptions,
    pcm: PcmStream,
    ready: VecDeque<Frame>,
    /// Set while a call works on the stream: still set after a panic, then the stream refuses work
    /// until `lg_stream_reset`.
    busy: bool,
}

/// Settings of a new stream. Start from `lg_stream_options_default()`; a NaN or negative value
/// takes the bundle's default.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct LgStreamOptions {
    /// Seed of the stream's sampler (one seed gives one motion, on every backend).
    pub seed: u64,
    /// Classifier-free guidance scale (NaN: the bundle's; 1.0 disables guidance).
    pub guidance: f64,
    /// LiveGesture: sampling temperature > 0 (NaN: the bundle's).
    pub temperature: f64,
    /// LiveGesture: keep the k most likely tokens, 0 = all (< 0: the bundle's).
    pub top_k: i64,
    /// DiffSHEG: DDIM steps (< 0: the bundle's).
    pub ddim_steps: i64,
    /// DiffSHEG: RePaint jumps per DDIM step (< 0: the bundle's).
    pub jumps: i64,
    /// DiffSHEG: window length in frames (< 0: the bundle's).
    pub window: i64,
    /// DiffSHEG: overlap of consecutive windows in frames (< 0: the bundle's).
    pub overlap: i64,
    /// DiffSHEG: last DDIM steps that blend the overlap (< 0: the bundle's).
    pub blend_steps: i64,
    /// DiffSHEG: style (speaker) id (< 0: the bundle's).
    pub speaker: i64,
}

impl LgStreamOptions {
    fn to_options(self) -> StreamOptions {
        let f = |x: f64| (!x.is_nan()).then_some(x);
        let n = |x: i64| usize::try_from(x).ok();
        StreamOptions {
            seed: self.seed,
            guidance: f(self.guidance),
            temperature: f(self.temperature),
            top_k: n(self.top_k),
            record_logits: false,
            ddim_steps: n(self.ddim_steps),
            jumps: n(self.jumps),
            window: n(self.window),
            overlap: n(self.overlap),
            blend_steps: n(self.blend_steps),
            speaker: n(self.speaker),
        }
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: &str) {
    let c = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// Runs one entry point: errors and panics become a status and the thread's last error message.
fn ffi(what: &str, f: impl FnOnce() -> Result<()>) -> LgStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => LgStatus::Ok,
        Ok(Err(e)) => {
            set_error(&format!("{e:#}"));
            match generate::classify(&e) {
                ErrorKind::NotFound => LgStatus::NotFound,
                ErrorKind::Io => LgStatus::Io,
                ErrorKind::Input => LgStatus::Input,
                ErrorKind::Runtime => LgStatus::Runtime,
            }
        }
        Err(p) => {
            set_error(&generate::panic_message(what, p.as_ref()));
            LgStatus::Panic
        }
    }
}

fn null(what: &str) -> anyhow::Error {
    InputError::new(format!("{what} is NULL")).into()
}

unsafe fn str_arg<'a>(p: *const c_char, what: &str) -> Result<Option<&'a str>> {
    if p.is_null() {
        return Ok(None);
    }
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map(Some)
        .map_err(|_| InputError::new(format!("{what} is not valid UTF-8")).into())
}

unsafe fn stream_mut<'a>(s: *mut LgStream) -> Result<&'a mut LgStream> {
    let s = unsafe { s.as_mut() }.ok_or_else(|| null("stream"))?;
    if s.busy {
        return Err(anyhow!(
            "stream: an earlier call failed with an internal error; lg_stream_reset() it to use it again"
        ));
    }
    Ok(s)
}

/// Runs `f` on the stream, marking it busy while it works (left set if `f` panics).
unsafe fn with_stream(s: *mut LgStream, f: impl FnOnce(&mut LgStream) -> Result<()>) -> Result<()> {
    let s = unsafe { stream_mut(s) }?;
    s.busy = true;
    let r = f(s);
    s.busy = false;
    r
}

unsafe fn write_out<T>(out: *mut T, value: T) {
    if let Some(o) = unsafe { out.as_mut() } {
        *o = value;
    }
}

/// The library's version, e.g. "0.1.0" (static string).
#[no_mangle]
pub extern "C" fn lg_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// The message of the last failed call on this thread ("" if none): valid until the next failing
/// call on this thread. Never NULL.
#[no_mangle]
pub extern "C" fn lg_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Options with every setting at the bundle's default and seed 0.
#[no_mangle]
pub extern "C" fn lg_stream_options_default() -> LgStreamOptions {
    LgStreamOptions {
        seed: 0,
        guidance: f64::NAN,
        temperature: f64::NAN,
        top_k: -1,
        ddim_steps: -1,
        jumps: -1,
        window: -1,
        overlap: -1,
        blend_steps: -1,
        speaker: -1,
    }
}

/// Loads the bundle in `bundle_dir` (NULL: `$LIVEGESTURE_BUNDLE`, else the repository's
/// `models/default` of the build) on `backend`: "tract" (NULL: the default) or "ort" (ONNX Runtime
/// from `$ORT_DYLIB_PATH`). Writes the handle to `*out` (free it with `lg_model_free`).
#[no_mangle]
pub unsafe extern "C" fn lg_model_load(
    bundle_dir: *const c_char,
    backend: *const c_char,
    out: *mut *mut LgModel,
) -> LgStatus {
    ffi("lg_model_load", || {
        if out.is_null() {
            return Err(null("out"));
        }
        unsafe { *out = std::ptr::null_mut() };
        let dir = unsafe { str_arg(bundle_dir, "bundle_dir") }?.map(PathBuf::from);
        let kind: BackendKind = match unsafe { str_arg(backend, "backend") }? {
            None => BackendKind::Tract,
            Some(b) => b.parse().map_err(InputError::new)?,
        };
        let opts = BackendOptions {
            kind,
            ..Default::default()
        };
        let model = generate::open_model(dir.as_deref(), &opts, GraphForm::Auto)?;
        let handle = Box::new(LgModel {
            inner: Arc::from(model),
        });
        unsafe { *out = Box::into_raw(handle) };
        Ok(())
    })
}

/// Frees a model (NULL: nothing). Streams made from it stay valid.
#[no_mangle]
pub unsafe extern "C" fn lg_model_free(model: *mut LgModel) {
    let _ = ffi("lg_model_free", || {
        if !model.is_null() {
            drop(unsafe { Box::from_raw(model) });
        }
        Ok(())
    });
}

/// A new stream of `model` (cold start) with `opts` (NULL: `lg_stream_options_default()`). Writes
/// the handle to `*out` (free it with `lg_stream_free`).
#[no_mangle]
pub unsafe extern "C" fn lg_stream_new(
    model: *const LgModel,
    opts: *const LgStreamOptions,
    out: *mut *mut LgStream,
) -> LgStatus {
    ffi("lg_stream_new", || {
        if out.is_null() {
            return Err(null("out"));
        }
        unsafe { *out = std::ptr::null_mut() };
        let model = unsafe { model.as_ref() }.ok_or_else(|| null("model"))?;
        let opts = unsafe { opts.as_ref() }
            .copied()
            .unwrap_or_else(|| lg_stream_options_default())
            .to_options();
        let stream = generate::new_stream(model.inner.as_ref(), &opts)?;
        let handle = Box::new(LgStream {
            model: model.inner.clone(),
            opts,
            pcm: PcmStream::new(stream, "stream"),
            ready: VecDeque::new(),
            busy: false,
        });
        unsafe { *out = Box::into_raw(handle) };
        Ok(())
    })
}

/// Frees a stream (NULL: nothing).
#[no_mangle]
pub unsafe extern "C" fn lg_stream_free(stream: *mut LgStream) {
    let _ = ffi("lg_stream_free", || {
        if !stream.is_null() {
            drop(unsafe { Box::from_raw(stream) });
        }
        Ok(())
    });
}

unsafe fn push(
    stream: *mut LgStream,
    samples: Vec<f32>,
    sample_rate: u32,
    frames_ready: *mut usize,
) -> Result<()> {
    unsafe {
        with_stream(stream, |s| {
            let frames = s.pcm.push(&samples, sample_rate)?;
            s.ready.extend(frames);
            write_out(frames_ready, s.ready.len());
            Ok(())
        })
    }
}

unsafe fn slice_arg<'a, T>(p: *const T, n: usize, what: &str) -> Result<&'a [T]> {
    if n == 0 {
        return Ok(&[]);
    }
    if p.is_null() {
        return Err(null(what));
    }
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// Pushes `n` mono float samples (in [-1, 1]) at `sample_rate` Hz (the first push fixes the stream's
/// rate; other rates than 16000 are resampled). The frames they complete wait to be read; their
/// count is written to `*frames_ready` (may be NULL). NaN or infinite samples are refused
/// (`LG_STATUS_INPUT`) before any reaches the stream.
#[no_mangle]
pub unsafe extern "C" fn lg_stream_push(
    stream: *mut LgStream,
    samples: *const f32,
    n: usize,
    sample_rate: u32,
    frames_ready: *mut usize,
) -> LgStatus {
    ffi("lg_stream_push", || unsafe {
        let s = slice_arg(samples, n, "samples")?.to_vec();
        push(stream, s, sample_rate, frames_ready)
    })
}

/// As `lg_stream_push`, with 16-bit samples (converted as x / 32768, as the WAV reader does).
#[no_mangle]
pub unsafe extern "C" fn lg_stream_push_i16(
    stream: *mut LgStream,
    samples: *const i16,
    n: usize,
    sample_rate: u32,
    frames_ready: *mut usize,
) -> LgStatus {
    ffi("lg_stream_push_i16", || unsafe {
        let s = generate::i16_to_f32(slice_arg(samples, n, "samples")?);
        push(stream, s, sample_rate, frames_ready)
    })
}

/// Ends the input: the remaining frames wait to be read, so that the stream's frames cover all the
/// audio pushed (ceil(n * 30 / rate) frames in all). `*frames_ready` as in `lg_stream_push`.
#[no_mangle]
pub unsafe extern "C" fn lg_stream_finish(
    stream: *mut LgStream,
    frames_ready: *mut usize,
) -> LgStatus {
    ffi("lg_stream_finish", || unsafe {
        with_stream(stream, |s| {
            let frames = s.pcm.finish()?;
            s.ready.extend(frames);
            write_out(frames_ready, s.ready.len());
            Ok(())
        })
    })
}

/// Generates the motion of a whole WAV file with this stream's options and seed, exactly as
/// `livegesture generate` (the same frames, bit for bit). The stream is reset first (frames not yet
/// read are dropped) and stays at a cold start afterwards; the file's frames wait to be read.
#[no_mangle]
pub unsafe extern "C" fn lg_stream_generate_wav(
    stream: *mut LgStream,
    wav_path: *const c_char,
    frames_ready: *mut usize,
) -> LgStatus {
    ffi("lg_stream_generate_wav", || unsafe {
        let path = str_arg(wav_path, "wav_path")?.ok_or_else(|| null("wav_path"))?;
        with_stream(stream, |s| {
            s.pcm.reset()?;
            s.ready.clear();
            let whole = generate::generate_wav(s.model.as_ref(), &s.opts, path.as_ref())?;
            s.ready.extend(whole.frames);
            write_out(frames_ready, s.ready.len());
            Ok(())
        })
    })
}

/// Frames waiting to be read (0 for a NULL stream).
#[no_mangle]
pub unsafe extern "C" fn lg_stream_frames_ready(stream: *const LgStream) -> usize {
    let mut n = 0;
    let _ = ffi("lg_stream_frames_ready", || {
        n = unsafe { stream.as_ref() }.map_or(0, |s| s.ready.len());
        Ok(())
    });
    n
}

/// Moves up to `max_frames` waiting frames, oldest first, into caller-owned buffers: `poses`
/// (max_frames x 165 floats), `trans` (x 3), `expressions` (x 100), `index` (frame indices); any
/// buffer may be NULL to skip that field. Writes the number of frames moved to `*frames_read`.
/// (`lg_stream_read_face` also gives the face channel.)
#[no_mangle]
pub unsafe extern "C" fn lg_stream_read(
    stream: *mut LgStream,
    max_frames: usize,
    poses: *mut f32,
    trans: *mut f32,
    expressions: *mut f32,
    index: *mut u64,
    frames_read: *mut usize,
) -> LgStatus {
    unsafe {
        lg_stream_read_face(
            stream,
            max_frames,
            poses,
            trans,
            expressions,
            index,
            ptr::null_mut(),
            frames_read,
        )
    }
}

/// As `lg_stream_read`, and the frames' face channel into `face` (max_frames `LgFace`s; NULL to
/// skip it). A model without the face channel (`lg_model_has_face` 0) refuses a non-NULL `face`
/// with `LG_STATUS_INPUT`, moving no frame.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn lg_stream_read_face(
    stream: *mut LgStream,
    max_frames: usize,
    poses: *mut f32,
    trans: *mut f32,
    expressions: *mut f32,
    index: *mut u64,
    face: *mut LgFace,
    frames_read: *mut usize,
) -> LgStatus {
    ffi("lg_stream_read", || unsafe {
        write_out(frames_read, 0);
        with_stream(stream, |s| {
            if !face.is_null() && !s.model.has_face() {
                return Err(InputError::new(
                    "face: this bundle has no face channel (lg_model_has_face is 0); pass NULL",
                )
                .into());
            }
            let n = max_frames.min(s.ready.len());
            for (i, f) in s.ready.drain(..n).enumerate() {
                copy_row(poses, i, &f.poses);
                copy_row(trans, i, &f.trans);
                copy_row(expressions, i, &f.expressions);
                if !index.is_null() {
                    *index.add(i) = f.index;
                }
                if !face.is_null() {
                    let v = f
                        .face
                        .ok_or_else(|| anyhow!("frame {} has no face values", f.index))?;
                    *face.add(i) = LgFace {
                        arkit: v.arkit,
                        visemes: v.visemes,
                    };
                }
            }
            write_out(frames_read, n);
            Ok(())
        })
    })
}

/// 1 if the model's frames carry the face channel (a bundle with a face graph; docs/face.md), 0
/// if not (or for NULL).
#[no_mangle]
pub unsafe extern "C" fn lg_model_has_face(model: *const LgModel) -> i32 {
    unsafe { model.as_ref() }.map_or(0, |m| i32::from(m.inner.has_face()))
}

/// The ARKit name of face weight `i` (0 ... 51), e.g. "jawOpen" (static string); NULL past the end.
#[no_mangle]
pub extern "C" fn lg_arkit_name(i: usize) -> *const c_char {
    static NAMES: OnceLock<Vec<CString>> = OnceLock::new();
    name_at(&NAMES, &livegesture::face::ARKIT_NAMES, i)
}

/// The viseme name of face probability `i` (0 ... 14), e.g. "aa" (static string); NULL past the end.
#[no_mangle]
pub extern "C" fn lg_viseme_name(i: usize) -> *const c_char {
    static NAMES: OnceLock<Vec<CString>> = OnceLock::new();
    name_at(&NAMES, &livegesture::face::VISEME_NAMES, i)
}

fn name_at(cell: &OnceLock<Vec<CString>>, names: &[&str], i: usize) -> *const c_char {
    let names = cell.get_or_init(|| {
        names
            .iter()
            .map(|n| CString::new(*n).expect("no NUL in a name"))
            .collect()
    });
    names.get(i).map_or(ptr::null(), |n| n.as_ptr())
}

unsafe fn copy_row(dst: *mut f32, row: usize, src: &[f32]) {
    if !dst.is_null() {
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst.add(row * src.len()), src.len()) };
    }
}

/// Back to a cold start with the same options and seed (also after an error, a panic or finish);
/// frames not yet read are dropped.
#[no_mangle]
pub unsafe extern "C" fn lg_stream_reset(stream: *mut LgStream) -> LgStatus {
    ffi("lg_stream_reset", || {
        let s = unsafe { stream.as_mut() }.ok_or_else(|| null("stream"))?;
        s.busy = true;
        s.pcm.reset()?;
        s.ready.clear();
        s.busy = false;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_a_status_and_a_message() {
        let st = ffi("lg_test", || panic!("boom"));
        assert_eq!(st, LgStatus::Panic);
        let msg = unsafe { CStr::from_ptr(lg_last_error()) }.to_str().unwrap();
        assert!(msg.contains("lg_test") && msg.contains("boom"), "{msg}");
    }

    #[test]
    fn errors_are_classified_and_kept_per_thread() {
        let st = ffi("x", || Err(InputError::new("bad thing").into()));
        assert_eq!(st, LgStatus::Input);
        let here = unsafe { CStr::from_ptr(lg_last_error()) }
            .to_str()
            .unwrap()
            .to_string();
        assert_eq!(here, "bad thing");
        let other = std::thread::spawn(|| {
            unsafe { CStr::from_ptr(lg_last_error()) }
                .to_str()
                .unwrap()
                .to_string()
        })
        .join()
        .unwrap();
        assert_eq!(other, "");
    }

    #[test]
    fn a_stream_that_panicked_refuses_work_until_reset() {
        let dir = livegesture_parity_tests::tiny_bundle();
        let dir = CString::new(dir.to_str().unwrap()).unwrap();
        let (mut m, mut s) = (std::ptr::null_mut(), std::ptr::null_mut());
        unsafe {
            assert_eq!(
                lg_model_load(dir.as_ptr(), std::ptr::null(), &mut m),
                LgStatus::Ok
            );
            assert_eq!(lg_stream_new(m, std::ptr::null(), &mut s), LgStatus::Ok);
            let st = ffi("lg_test", || with_stream(s, |_| panic!("inside a stream")));
            assert_eq!(st, LgStatus::Panic);
            let x = [0.0f32; 100];
            let mut ready = 0;
            assert_eq!(
                lg_stream_push(s, x.as_ptr(), 100, 16000, &mut ready),
                LgStatus::Runtime
            );
            let msg = CStr::from_ptr(lg_last_error()).to_str().unwrap();
            assert!(msg.contains("lg_stream_reset"), "{msg}");
            assert_eq!(lg_stream_reset(s), LgStatus::Ok);
            assert_eq!(
                lg_stream_push(s, x.as_ptr(), 100, 16000, &mut ready),
                LgStatus::Ok
            );
            lg_stream_free(s);
            lg_model_free(m);
        }
    }

    #[test]
    fn constants_are_the_librarys() {
        assert_eq!(LG_POSE_DIM, livegesture::output::POSE_DIM);
        assert_eq!(LG_TRANS_DIM, livegesture::output::TRANS_DIM);
        assert_eq!(LG_EXPR_DIM, livegesture::output::EXPR_DIM);
        assert_eq!(LG_FPS, livegesture::output::FPS);
    }

    #[test]
    fn default_options_take_the_bundles_defaults() {
        let o = lg_stream_options_default().to_options();
        assert_eq!(o, StreamOptions::default());
    }
}
