//! The errors every door maps to its own (the CLI's exit codes and flags, Python's exceptions, C's status
//! codes): [`InputError`] (bad input, with the options it concerns), [`ErrorKind`] and [`classify`].
//! A leaf below the models and [`crate::generate`] (both use it; re-exported there).

use crate::audio::AudioError;
use crate::bundle::BundleError;

/// Bad input given to the library, a tool or a binding (options, audio arrays, a stream used out of
/// turn, arguments): the one input error type of every door.
///
/// `fields` names the options it concerns as [`crate::model::StreamOptions`] spells them (`guidance`,
/// `ddim_steps`); the message follows them ("ddim_steps only apply to DiffSHEG bundles ..."). Each
/// door names them its own way ([`InputError::render`]): the CLI as flags (`--ddim-steps`),
/// Python as keyword arguments, C as `LgStreamOptions` fields (both the names as they are). Library
/// messages never carry a door's spelling.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputError {
    /// The options concerned (empty: the input as a whole).
    pub fields: Vec<&'static str>,
    /// What is wrong and what was expected (after the fields, if any).
    pub message: String,
}

impl InputError {
    /// An error about the input as a whole.
    pub fn new(message: impl Into<String>) -> Self {
        Self {
            fields: Vec::new(),
            message: message.into(),
        }
    }

    /// An error about the options `fields` (names as in [`crate::model::StreamOptions`]); `message` follows them.
    pub fn fields(fields: Vec<&'static str>, message: impl Into<String>) -> Self {
        Self {
            fields,
            message: message.into(),
        }
    }

    /// The text with each field spelled by `name` (the CLI passes `--` and dashes).
    pub fn render(&self, name: impl Fn(&str) -> String) -> String {
        if self.fields.is_empty() {
            return self.message.clone();
        }
        let names: Vec<String> = self.fields.iter().map(|f| name(f)).collect();
        format!("{} {}", names.join(", "), self.message)
    }
}

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.render(str::to_string))
    }
}

impl std::error::Error for InputError {}

/// What kind of failure an error is, for a binding's error types (Python exceptions, C status codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// A file or folder that is not there (a WAV file, a bundle, a graph file the manifest lists).
    NotFound,
    /// Another failure reading a file.
    Io,
    /// Bad input: audio, bundle contents, options, a stream used out of turn.
    Input,
    /// Anything else (a backend failure): not the caller's input.
    Runtime,
}

/// Classifies `e` by the first typed error in its chain ([`AudioError`], [`BundleError`],
/// [`InputError`], [`std::io::Error`]).
pub fn classify(e: &anyhow::Error) -> ErrorKind {
    for cause in e.chain() {
        if let Some(a) = cause.downcast_ref::<AudioError>() {
            return match a {
                AudioError::NotFound { .. } => ErrorKind::NotFound,
                AudioError::Io { .. } => ErrorKind::Io,
                _ => ErrorKind::Input,
            };
        }
        if let Some(b) = cause.downcast_ref::<BundleError>() {
            return match b {
                BundleError::NoManifest { .. } | BundleError::MissingFile { .. } => {
                    ErrorKind::NotFound
                }
                BundleError::Io { .. } => ErrorKind::Io,
                _ => ErrorKind::Input,
            };
        }
        if cause.is::<InputError>() {
            return ErrorKind::Input;
        }
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            return if io.kind() == std::io::ErrorKind::NotFound {
                ErrorKind::NotFound
            } else {
                ErrorKind::Io
            };
        }
    }
    ErrorKind::Runtime
}
