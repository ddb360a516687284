//! [`Modem`]: one concrete driver type for the configured modem protocol.
//!
//! [`ModemDriver`] returns `impl Future`, so it is not object-safe and `Box<dyn
//! ModemDriver>` is impossible; an enum over the drivers Shoal ships is the simple way to
//! choose one from configuration at run time.

use shoal_acoustic::driver::{
    AtDriver, DriverConfig, ModemDriver, NlDriver, OutFrame, Outcome, RxFrame, TransmitError,
    Withdrawal,
};

use shoal_acoustic::relay::{RelayConfig, RelayDriver};

use crate::config::{ModemKind, ModemSettings};
use crate::error::ConverterError;

/// A modem driver chosen from [`ModemSettings`].
#[derive(Debug)]
#[non_exhaustive]
pub enum Modem {
    /// EvoLogics S2C AT interface.
    At(AtDriver),
    /// EviNS network layer.
    Nl(NlDriver),
}

impl Modem {
    /// Starts the driver for `settings`; it connects (and reconnects after a drop) in the
    /// background. `time_scale` shrinks its timers to match a faster-than-real-time
    /// emulator (1.0 for a real modem). Must be called inside a tokio runtime.
    pub fn start(settings: &ModemSettings, time_scale: f64) -> Self {
        let cfg = DriverConfig::new(settings.address).scaled(time_scale);
        match settings.kind {
            ModemKind::EvologicsAt => Self::At(AtDriver::start(cfg)),
            ModemKind::EvinsNl => Self::Nl(NlDriver::start(cfg, settings.nl_delivery_reports)),
        }
    }

    /// [`Self::start`] under a relay layer with `relay`'s settings
    /// (docs/acoustic.md#multi-hop-relays): frames for a node behind a relay leave
    /// enveloped, and, with `relay.forward`, frames for others are forwarded. Put a
    /// [`shoal_acoustic::secure::TaggedDriver`] on top, never under it, so tags stay end
    /// to end.
    pub fn start_relayed(
        settings: &ModemSettings,
        relay: RelayConfig,
        time_scale: f64,
    ) -> Result<RelayDriver<Self>, ConverterError> {
        RelayDriver::start(Self::start(settings, time_scale), relay, time_scale)
            .map_err(|e| ConverterError::Config(e.to_string()))
    }
}

impl ModemDriver for Modem {
    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        match self {
            Self::At(d) => d.transmit(frame).await,
            Self::Nl(d) => d.transmit(frame).await,
        }
    }

    async fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> Result<Outcome, TransmitError> {
        match self {
            Self::At(d) => d.transmit_withdrawable(frame, withdrawal).await,
            Self::Nl(d) => d.transmit_withdrawable(frame, withdrawal).await,
        }
    }

    async fn receive(&self) -> Option<RxFrame> {
        match self {
            Self::At(d) => d.receive().await,
            Self::Nl(d) => d.receive().await,
        }
    }

    fn local_address(&self) -> Option<u8> {
        match self {
            Self::At(d) => d.local_address(),
            Self::Nl(d) => d.local_address(),
        }
    }

    fn is_connected(&self) -> bool {
        match self {
            Self::At(d) => d.is_connected(),
            Self::Nl(d) => d.is_connected(),
        }
    }
}
