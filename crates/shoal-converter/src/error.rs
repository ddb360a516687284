//! Errors of the converter.

use shoal_dds::CreateError;

/// Why a VDT or CDT could not start or had to stop.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConverterError {
    /// The configuration is unusable; the message names the key.
    #[error("invalid converter configuration: {0}")]
    Config(String),
    /// A DDS reader or writer could not be created.
    #[error(transparent)]
    Dds(#[from] CreateError),
    /// The acoustic link stopped (its modem driver ended) while the converter ran.
    #[error("acoustic link stopped")]
    LinkStopped,
    /// The modem emulator of an emulated relay could not start.
    #[error("modem emulator: {0}")]
    Emulator(#[from] shoal_acoustic::emulator::EmulatorError),
}
