//! The wire protocol of docs/serve.md: query parameters, client messages, close codes, and
//! [`SessionInput`], everything a session does with the bytes a client sends (no socket, no
//! scheduler: the `serve_protocol` fuzz target drives it directly).

use livegesture::audio::{AudioSpan, RawFormat, RawPcmDecoder, Resampler16k};

/// Close code: normal end after `{"type":"done"}`.
pub const CLOSE_NORMAL: u16 = 1000;
/// Close code: the server is shutting down.
pub const CLOSE_GOING_AWAY: u16 = 1001;
/// Close code: a message of a kind the server does not accept (unknown `type`, audio after `end`).
pub const CLOSE_UNSUPPORTED: u16 = 1003;
/// Close code: a malformed message (not a JSON object with a `type`, non-finite float samples, a
/// stream ending in the middle of a sample frame).
pub const CLOSE_INVALID: u16 = 1007;
/// Close code: idle past the timeout, or a client too slow to take its frames.
pub const CLOSE_POLICY: u16 = 1008;
/// Close code: a message over the size limit.
pub const CLOSE_TOO_BIG: u16 = 1009;
/// Close code: an internal error (a failed graph run).
pub const CLOSE_INTERNAL: u16 = 1011;
/// Close code: at capacity (the server refuses with HTTP 503 before the upgrade where it can).
pub const CLOSE_TRY_AGAIN: u16 = 1013;

/// Frame message encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    /// One text message per frame: the `livegesture stream` JSON line object.
    Json,
    /// One binary message per frame: the 1104-byte record of `stream --output binary`.
    Binary,
}

impl OutputKind {
    pub fn name(self) -> &'static str {
        match self {
            OutputKind::Json => "json",
            OutputKind::Binary => "binary",
        }
    }
}

/// The validated query parameters of `GET /v1/stream`.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionParams {
    /// Input sample rate in Hz.
    pub rate: u32,
    /// Interleaved input channels.
    pub channels: u16,
    /// Input sample encoding (`s16le` or `f32le`).
    pub format: RawFormat,
    /// Sampler seed.
    pub seed: u64,
    /// Guidance scale (`None`: the bundle's).
    pub guidance: Option<f64>,
    /// Frame encoding.
    pub output: OutputKind,
}

/// Lowest accepted input rate (Hz), telephone speech. Resampling to 16 kHz multiplies the samples by
/// `16000 / rate`: a lower rate let one small message (or the resampler's buffers, sized by the ratio)
/// take unbounded time and memory: at `rate=1` one 4 KiB message took over 30 s and a 1 MiB message
/// would need 34 GB (found fuzzing, `fuzz/regressions/serve_protocol/`). At 8 kHz the output is at most
/// twice the input.
pub const MIN_RATE: u32 = 8_000;
/// Highest accepted input rate (Hz).
pub const MAX_RATE: u32 = 384_000;
/// Most accepted input channels.
pub const MAX_CHANNELS: u16 = 32;

impl SessionParams {
    /// Parses the query pairs; an error is the HTTP 400 body.
    pub fn parse(pairs: &[(String, String)]) -> Result<Self, String> {
        let mut p = SessionParams {
            rate: 16000,
            channels: 1,
            format: RawFormat::S16Le,
            seed: 0,
            guidance: None,
            output: OutputKind::Json,
        };
        let mut seen: Vec<&str> = Vec::new();
        for (k, v) in pairs {
            if seen.contains(&k.as_str()) {
                return Err(format!("query parameter '{k}' is given more than once"));
            }
            seen.push(k);
            match k.as_str() {
                "rate" => {
                    p.rate = v
                        .parse::<u32>()
                        .ok()
                        .filter(|r| (MIN_RATE..=MAX_RATE).contains(r))
                        .ok_or_else(|| {
                            format!("rate={v:?}: expected an integer sample rate in Hz, {MIN_RATE} to {MAX_RATE}")
                        })?
                }
                "channels" => {
                    p.channels = v
                        .parse::<u16>()
                        .ok()
                        .filter(|c| (1..=MAX_CHANNELS).contains(c))
                        .ok_or_else(|| {
                            format!("channels={v:?}: expected an integer channel count, 1 to {MAX_CHANNELS}")
                        })?
                }
                "format" => {
                    p.format = match v.as_str() {
                        "s16le" => RawFormat::S16Le,
                        "f32le" => RawFormat::F32Le,
                        _ => return Err(format!("format={v:?}: expected s16le or f32le")),
                    }
                }
                "seed" => {
                    p.seed = v.parse::<u64>().map_err(|_| {
                        format!("seed={v:?}: expected an unsigned 64-bit integer")
                    })?
                }
                "guidance" => {
                    let g = v
                        .parse::<f64>()
                        .ok()
                        .filter(|g| g.is_finite())
                        .ok_or_else(|| format!("guidance={v:?}: expected a finite number"))?;
                    p.guidance = Some(g);
                }
                "output" => {
                    p.output = match v.as_str() {
                        "json" => OutputKind::Json,
                        "binary" => OutputKind::Binary,
                        _ => return Err(format!("output={v:?}: expected json or binary")),
                    }
                }
                other => {
                    return Err(format!(
                        "unknown query parameter '{other}'; expected rate, channels, format, seed, guidance or output"
                    ))
                }
            }
        }
        Ok(p)
    }

    /// Bytes of one input frame (one sample of every channel).
    pub fn frame_bytes(&self) -> usize {
        self.channels as usize * self.format.bytes_per_sample()
    }
}

/// A text message from the client.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientText {
    /// `{"type":"end"}`.
    End,
}

/// Why a text message was refused: (close code, reason).
pub fn parse_client_text(text: &str) -> Result<ClientText, (u16, String)> {
    let v: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| (CLOSE_INVALID, format!("malformed message: not JSON ({e})")))?;
    let obj = v.as_object().ok_or_else(|| {
        (
            CLOSE_INVALID,
            "malformed message: expected a JSON object with a \"type\"".to_string(),
        )
    })?;
    let ty = obj.get("type").and_then(|t| t.as_str()).ok_or_else(|| {
        (
            CLOSE_INVALID,
            "malformed message: no string \"type\" field".to_string(),
        )
    })?;
    match ty {
        "end" => Ok(ClientText::End),
        other => Err((
            CLOSE_UNSUPPORTED,
            format!(
                "unknown message type {:?}; the client sends binary PCM and {{\"type\":\"end\"}}",
                truncate(other, 40)
            ),
        )),
    }
}

/// A client message refused: the session closes with `code` and `reason`; `metric` is the
/// refusal counter it increments (`None`: an internal error, not counted as a refusal).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    pub code: u16,
    pub metric: Option<&'static str>,
    pub reason: String,
}

impl Refusal {
    fn new(code: u16, metric: Option<&'static str>, reason: String) -> Self {
        Self {
            code,
            metric,
            reason,
        }
    }
}

/// A session's input side: decodes the client's binary PCM messages (samples and frames may straddle
/// messages), resamples to 16 kHz and handles the text messages. Its 16 kHz output goes to the
/// scheduler; a [`Refusal`] ends the session.
#[derive(Debug)]
pub struct SessionInput {
    decoder: RawPcmDecoder,
    resampler: Resampler16k,
    rate: u32,
    frame_bytes: u64,
    in_bytes: u64,
    ended: bool,
}

/// What the client's `{"type":"end"}` leaves: the last 16 kHz samples and the input received.
#[derive(Debug, Clone, PartialEq)]
pub struct InputEnd {
    /// The resampler's tail.
    pub tail: Vec<f32>,
    /// All input received, at the client's rate (it fixes the frame count, docs/output.md).
    pub input: AudioSpan,
}

impl SessionInput {
    /// The decoder and resampler for `params`; `origin` names the session in error messages. An
    /// error here is internal (the parameters were validated by [`SessionParams::parse`]).
    pub fn new(params: &SessionParams, origin: String) -> Result<Self, String> {
        let decoder = RawPcmDecoder::new(params.format, params.channels, origin.clone())
            .map_err(|e| e.to_string())?;
        let resampler = Resampler16k::new(params.rate, origin).map_err(|e| e.to_string())?;
        Ok(Self {
            decoder,
            resampler,
            rate: params.rate,
            frame_bytes: params.frame_bytes() as u64,
            in_bytes: 0,
            ended: false,
        })
    }

    /// True after `{"type":"end"}` or [`SessionInput::drain`].
    pub fn ended(&self) -> bool {
        self.ended
    }

    /// The server is shutting down: no more input is taken (audio or `end` are refused with 1003).
    pub fn drain(&mut self) {
        self.ended = true;
    }

    /// A binary message: interleaved PCM. Returns the 16 kHz samples it completes (possibly none).
    pub fn binary(&mut self, bytes: &[u8]) -> Result<Vec<f32>, Refusal> {
        if self.ended {
            return Err(Refusal::new(
                CLOSE_UNSUPPORTED,
                Some("unknown_message"),
                "audio after {\"type\":\"end\"}".to_string(),
            ));
        }
        self.in_bytes += bytes.len() as u64;
        let mono = self.decoder.decode(bytes).map_err(|e| {
            Refusal::new(
                CLOSE_INVALID,
                Some("malformed"),
                format!("malformed audio: {e}"),
            )
        })?;
        self.resampler
            .push(&mono)
            .map_err(|e| Refusal::new(CLOSE_INTERNAL, None, format!("{e}")))
    }

    /// A text message. `{"type":"end"}` ends the input: the decoder must hold no partial frame;
    /// returns the resampler's tail and the input span. Anything else is refused.
    pub fn text(&mut self, text: &str) -> Result<InputEnd, Refusal> {
        match parse_client_text(text) {
            Ok(ClientText::End) if !self.ended => {
                self.decoder.finish().map_err(|e| {
                    Refusal::new(
                        CLOSE_INVALID,
                        Some("malformed"),
                        format!("malformed audio: {e}"),
                    )
                })?;
                let tail = self
                    .resampler
                    .finish()
                    .map_err(|e| Refusal::new(CLOSE_INTERNAL, None, format!("{e}")))?;
                self.ended = true;
                Ok(InputEnd {
                    tail,
                    input: AudioSpan::new(self.in_bytes / self.frame_bytes, self.rate),
                })
            }
            Ok(ClientText::End) => Err(Refusal::new(
                CLOSE_UNSUPPORTED,
                Some("unknown_message"),
                "a second {\"type\":\"end\"}".to_string(),
            )),
            Err((code, reason)) => {
                let metric = if code == CLOSE_UNSUPPORTED {
                    "unknown_message"
                } else {
                    "malformed"
                };
                Err(Refusal::new(code, Some(metric), reason))
            }
        }
    }
}

/// `s` cut to at most `n` bytes on a character boundary.
pub fn truncate(s: &str, n: usize) -> &str {
    if s.len() <= n {
        return s;
    }
    let mut i = n;
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    &s[..i]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q(s: &[(&str, &str)]) -> Vec<(String, String)> {
        s.iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    }

    #[test]
    fn defaults_and_values() {
        let p = SessionParams::parse(&[]).unwrap();
        assert_eq!(
            (p.rate, p.channels, p.format, p.seed, p.guidance, p.output),
            (16000, 1, RawFormat::S16Le, 0, None, OutputKind::Json)
        );
        let p = SessionParams::parse(&q(&[
            ("rate", "44100"),
            ("channels", "2"),
            ("format", "f32le"),
            ("seed", "7"),
            ("guidance", "1.5"),
            ("output", "binary"),
        ]))
        .unwrap();
        assert_eq!(
            (p.rate, p.channels, p.format, p.seed, p.guidance, p.output),
            (44100, 2, RawFormat::F32Le, 7, Some(1.5), OutputKind::Binary)
        );
        for bad in [
            ("rate", "0"),
            ("rate", "7999"),
            ("rate", "384001"),
            ("rate", "x"),
            ("channels", "0"),
            ("format", "s32le"),
            ("seed", "-1"),
            ("guidance", "nan"),
            ("output", "xml"),
            ("volume", "3"),
        ] {
            let e = SessionParams::parse(&q(&[bad])).unwrap_err();
            assert!(e.contains(bad.0), "{e}");
        }
        assert!(SessionParams::parse(&q(&[("seed", "1"), ("seed", "2")])).is_err());
    }

    #[test]
    fn client_text() {
        assert_eq!(parse_client_text(r#"{"type":"end"}"#), Ok(ClientText::End));
        assert_eq!(parse_client_text("nope").unwrap_err().0, CLOSE_INVALID);
        assert_eq!(parse_client_text("[1]").unwrap_err().0, CLOSE_INVALID);
        assert_eq!(
            parse_client_text(r#"{"type":3}"#).unwrap_err().0,
            CLOSE_INVALID
        );
        assert_eq!(
            parse_client_text(r#"{"type":"pause"}"#).unwrap_err().0,
            CLOSE_UNSUPPORTED
        );
    }

    fn input(q_: &[(&str, &str)]) -> SessionInput {
        SessionInput::new(&SessionParams::parse(&q(q_)).unwrap(), "test".into()).unwrap()
    }

    #[test]
    fn session_input_split_samples_and_end() {
        // 16 kHz s16le stereo: frames straddle messages; the mono mix passes through
        let mut i = input(&[("channels", "2")]);
        let pcm: Vec<u8> = [1000i16, 3000, -2000, 0, 16384, 16384]
            .iter()
            .flat_map(|s| s.to_le_bytes())
            .collect();
        let mut out = i.binary(&pcm[..3]).unwrap();
        out.extend(i.binary(&pcm[3..9]).unwrap());
        out.extend(i.binary(&pcm[9..]).unwrap());
        assert_eq!(out, vec![2000.0 / 32768.0, -1000.0 / 32768.0, 0.5]);
        let end = i.text(r#"{"type":"end"}"#).unwrap();
        assert!(end.tail.is_empty());
        assert_eq!(end.input, AudioSpan::new(3, 16000));
        assert!(i.ended());
        let r = i.binary(&[0, 0]).unwrap_err();
        assert_eq!(
            (r.code, r.metric),
            (CLOSE_UNSUPPORTED, Some("unknown_message"))
        );
        let r = i.text(r#"{"type":"end"}"#).unwrap_err();
        assert_eq!(
            (r.code, r.metric),
            (CLOSE_UNSUPPORTED, Some("unknown_message"))
        );
    }

    #[test]
    fn session_input_refusals() {
        // a partial sample frame at the end
        let mut i = input(&[]);
        assert!(i.binary(&[1, 2, 3]).unwrap().len() == 1);
        let r = i.text(r#"{"type":"end"}"#).unwrap_err();
        assert_eq!((r.code, r.metric), (CLOSE_INVALID, Some("malformed")));
        assert!(r.reason.contains("malformed audio"), "{}", r.reason);
        // non-finite float samples
        let mut i = input(&[("format", "f32le")]);
        let r = i.binary(&f32::NAN.to_le_bytes()).unwrap_err();
        assert_eq!((r.code, r.metric), (CLOSE_INVALID, Some("malformed")));
        // unknown and malformed text
        let mut i = input(&[]);
        assert_eq!(
            i.text(r#"{"type":"pause"}"#).unwrap_err().code,
            CLOSE_UNSUPPORTED
        );
        assert_eq!(i.text("{").unwrap_err().metric, Some("malformed"));
        // draining: no more input
        let mut i = input(&[("rate", "44100")]);
        i.drain();
        assert_eq!(i.binary(&[0, 0]).unwrap_err().code, CLOSE_UNSUPPORTED);
    }

    #[test]
    fn session_input_resamples_to_the_promised_length() {
        let mut i = input(&[("rate", "44100"), ("format", "f32le")]);
        let pcm: Vec<u8> = (0..4410)
            .flat_map(|k| ((k as f32 * 0.01).sin() * 0.5).to_le_bytes())
            .collect();
        let mut n = 0;
        for c in pcm.chunks(1001) {
            n += i.binary(c).unwrap().len();
        }
        let end = i.text(r#"{"type":"end"}"#).unwrap();
        assert_eq!(end.input, AudioSpan::new(4410, 44100));
        assert_eq!(n + end.tail.len(), 1600);
    }
}
