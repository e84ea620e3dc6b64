//! The command-line front end: argument parsing and the subcommands. Each
//! subcommand lives in its own file and calls the pure library modules.

use clap::{Parser, Subcommand};

#[cfg(feature = "synth")]
pub mod demo_cmd;
pub mod init_cmd;
pub mod meta_cmd;
pub mod process_cmd;
pub mod serve_cmd;
#[cfg(feature = "synth")]
pub mod synth_cmd;

/// Command line of the `semdepth` binary.
#[derive(Debug, Parser)]
#[command(
    name = "semdepth",
    version,
    about = "Depth of a tracked object from SEM stereo pairs"
)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Write a synthetic SEM stereo sequence with ground truth (truth.json).
    #[cfg(feature = "synth")]
    Synth(synth_cmd::SynthArgs),
    /// Find the object in one image and print its initial contour as JSON.
    Init(init_cmd::InitArgs),
    /// Print the pixel size, stage tilt and working distance the microscope wrote into each image, as JSON.
    Meta(meta_cmd::MetaArgs),
    /// Track a folder of stereo pairs and print one record per pair.
    Process(process_cmd::ProcessArgs),
    /// Stream a synthetic sequence through the service and print true and measured z.
    #[cfg(feature = "synth")]
    Demo(demo_cmd::DemoArgs),
    /// Run the HTTP/WebSocket depth service.
    Serve(serve_cmd::ServeArgs),
    /// Print the service's OpenAPI document.
    Openapi(serve_cmd::OpenapiArgs),
    /// Ask a running server whether it is alive (exit 0) or not (exit 1).
    Healthcheck(serve_cmd::HealthcheckArgs),
}

/// A failed command: the message goes to stderr, the code is the exit status.
#[derive(Debug)]
pub struct CliError {
    /// Process exit code (2: bad arguments or input, 3: nothing found, 1: other).
    pub exit_code: i32,
    /// Human-readable explanation.
    pub message: String,
}

impl CliError {
    /// An error caused by the user's input (exit code 2).
    pub fn input(message: impl Into<String>) -> Self {
        Self {
            exit_code: 2,
            message: message.into(),
        }
    }

    /// An error with an explicit exit code.
    pub fn with_code(exit_code: i32, message: impl Into<String>) -> Self {
        Self {
            exit_code,
            message: message.into(),
        }
    }
}

impl std::fmt::Display for CliError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl From<semdepth_core::imageio::ImageInputError> for CliError {
    fn from(e: semdepth_core::imageio::ImageInputError) -> Self {
        Self::input(format!("error[{}]: {e}", e.code()))
    }
}

/// An invalid hint (`roi`, `point`) as an input error (exit 2),
/// `error[invalid_hint]: invalid SOURCE: ...`, where `source` names where
/// the hint came from: the flag (`--roi`) or the params file's field.
pub fn hint_error(e: &semdepth_core::init::InitError, source: impl Fn(&str) -> String) -> CliError {
    match e {
        semdepth_core::init::InitError::InvalidHint { field, message } => CliError::input(format!(
            "error[{}]: invalid {}: {message}",
            e.code(),
            source(field)
        )),
        other => CliError::input(format!("error[{}]: {other}", other.code())),
    }
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<(), CliError> {
    match cli.command {
        #[cfg(feature = "synth")]
        Command::Synth(args) => synth_cmd::run(args),
        Command::Init(args) => init_cmd::run(args),
        Command::Meta(args) => meta_cmd::run(args),
        Command::Process(args) => process_cmd::run(args),
        Command::Serve(args) => serve_cmd::run(args),
        #[cfg(feature = "synth")]
        Command::Demo(args) => demo_cmd::run(args),
        Command::Openapi(args) => serve_cmd::run_openapi(args),
        Command::Healthcheck(args) => serve_cmd::run_healthcheck(args),
    }
}

/// The `N` numbers of flag `--name`, given as `N` values or comma-separated
/// (`--roi 10 20 30 40` or `--roi 10,20,30,40`); exit 2 naming the flag
/// otherwise.
pub(crate) fn exactly<const N: usize, T: Copy>(name: &str, values: &[T]) -> Result<[T; N], CliError> {
    <[T; N]>::try_from(values).map_err(|_| {
        CliError::input(format!(
            "error[invalid_hint]: --{name} takes {N} numbers, separated by spaces or commas (got {})",
            values.len()
        ))
    })
}

/// `values` as `[x, y]` pairs for the hint `--{name}` (an outline's
/// vertices, points that are not the object): an even count of at least
/// `2 * min_pairs` numbers.
pub(crate) fn pairs(name: &str, values: &[f64], min_pairs: usize) -> Result<Vec<[f64; 2]>, CliError> {
    crate::service::api::params::xy_pairs(values, min_pairs).ok_or_else(|| {
        CliError::input(format!(
            "error[invalid_hint]: --{name} takes X,Y pairs, at least {min_pairs} (got {} numbers)",
            values.len()
        ))
    })
}

/// The generator's scene conditions as a command-line value.
#[cfg(feature = "synth")]
pub(crate) fn preset_value() -> impl clap::builder::TypedValueParser<Value = semdepth_core::synth::Preset> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    use semdepth_core::synth::Preset;
    PossibleValuesParser::new(Preset::ALL.map(|p| PossibleValue::new(p.name())))
        .map(|name| Preset::from_name(&name).expect("one of the possible values"))
}

/// The generator's object shapes as a command-line value.
#[cfg(feature = "synth")]
pub(crate) fn shape_value() -> impl clap::builder::TypedValueParser<Value = semdepth_core::synth::Shape> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    use semdepth_core::synth::Shape;
    PossibleValuesParser::new(Shape::ALL.map(|s| PossibleValue::new(s.name())))
        .map(|name| Shape::from_name(&name).expect("one of the possible values"))
}
