//! The acoustic demo `shoal up` includes: simulated submerged vehicles heard by the station
//! only through an emulated acoustic relay (AUV →acoustic→ USV (CDT) →DDS over IP→
//! station, the SWARMs sea-trial topology).
//!
//! The relay itself (emulated modems, a VDT per vehicle on its private DDS domain, the CDT
//! on the station's) is [`shoal_converter::emulated_relay`]; this module puts the vehicle
//! simulator ([`shoal_proxy::run_sim`]) behind it.

use std::collections::HashMap;
use std::sync::Arc;

use anyhow::Result;
use shoal_acoustic::channel::ChannelModel;
use shoal_converter::emulated_relay::{
    AcousticKeys, EmulatedRelayConfig, RelayedVehicle, run_emulated_relay,
};
use shoal_converter::{ConverterError, FrameTap};
use shoal_dds::PubSub;
use shoal_model::VehicleKind;
use shoal_proxy::sim::{OceanField, SimSettings, SimSpec};
use tokio_util::sync::CancellationToken;

/// One submerged vehicle of the demo.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoVehicle {
    /// The simulated vehicle (id, kind, start position, state rate).
    pub sim: SimSpec,
    /// Its acoustic address, 1..=15, distinct from the relay's.
    pub address: u8,
    /// Its private DDS domain (vehicle side); must differ from the station's.
    pub domain_id: u16,
}

/// Configuration of the acoustic demo.
#[derive(Debug, Clone, PartialEq)]
pub struct AcousticDemoConfig {
    /// The submerged vehicles.
    pub vehicles: Vec<DemoVehicle>,
    /// Acoustic address of the relay's modem (the CDT).
    pub relay_address: u8,
    /// Relay position, degrees.
    pub relay_latitude_deg: f64,
    /// Relay position, degrees.
    pub relay_longitude_deg: f64,
    /// A fixed packet error rate instead of the channel's physics.
    pub fixed_per: Option<f64>,
    /// The vehicle on the station's domain carrying the relay, which the relay follows.
    pub relay_vehicle: Option<String>,
    /// The ocean the vehicles sample.
    pub ocean: OceanField,
    /// The channel's physics.
    pub channel: ChannelModel,
}

impl Default for AcousticDemoConfig {
    fn default() -> Self {
        // Off Trondheim like the default fleet; the relay rides on usv-1 (the default
        // fleet's USV), starting at its start position about 520 m from the AUV. Without a
        // usv-1 on the station's domain it stays there.
        Self {
            vehicles: vec![DemoVehicle {
                sim: SimSpec {
                    id: "auv-ac1".into(),
                    kind: VehicleKind::Auv,
                    latitude_deg: 63.4670,
                    longitude_deg: 10.3720,
                    rate_hz: 1.0,
                    battery_pct: 100.0,
                },
                address: 2,
                domain_id: 100,
            }],
            relay_address: 1,
            relay_latitude_deg: 63.4640,
            relay_longitude_deg: 10.3800,
            fixed_per: None,
            relay_vehicle: Some("usv-1".into()),
            ocean: OceanField::default(),
            channel: ChannelModel::default(),
        }
    }
}

impl AcousticDemoConfig {
    /// The acoustic vehicles and relay of a scenario, each vehicle on private DDS domain
    /// 100, 101, ...; `None` when it has none.
    pub fn from_scenario(s: &shoal_scenario::Scenario) -> Option<Self> {
        let net = s.acoustic.as_ref()?;
        let vehicles: Vec<DemoVehicle> = s
            .acoustic_vehicles()
            .zip(100u16..)
            .filter_map(|(v, domain_id)| {
                Some(DemoVehicle {
                    sim: crate::scenario::sim_spec(v),
                    address: v.acoustic_address?,
                    domain_id,
                })
            })
            .collect();
        (!vehicles.is_empty()).then_some(Self {
            vehicles,
            relay_address: net.relay_address,
            relay_latitude_deg: net.relay_latitude_deg,
            relay_longitude_deg: net.relay_longitude_deg,
            fixed_per: net.fixed_per,
            relay_vehicle: net.relay_vehicle.clone(),
            ocean: s.environment.clone(),
            channel: net.channel,
        })
    }

    /// The relay that carries the demo's vehicles (real time, channel physics).
    fn relay(&self) -> EmulatedRelayConfig {
        let vehicles = self
            .vehicles
            .iter()
            .map(|v| RelayedVehicle {
                id: v.sim.id.clone(),
                address: v.address,
                domain_id: v.domain_id,
                latitude_deg: v.sim.latitude_deg,
                longitude_deg: v.sim.longitude_deg,
            })
            .collect();
        let mut relay = EmulatedRelayConfig::new(
            self.relay_address,
            self.relay_latitude_deg,
            self.relay_longitude_deg,
            vehicles,
        );
        relay.fixed_per = self.fixed_per;
        relay.channel = self.channel;
        relay.relay_vehicle.clone_from(&self.relay_vehicle);
        relay
    }
}

/// Runs the acoustic demo until `shutdown`: each simulated vehicle on its private domain,
/// heard through the relay whose CDT publishes with `cdt_dds` on the station's domain
/// (with security on, a signing participant), its frames tagged with `keys` if given and
/// reported to `tap` if given (`[recorder] acoustic`).
///
/// Returns an error if the relay or a simulated vehicle cannot start or stops on its own;
/// everything it started is stopped.
pub async fn run_acoustic_demo(
    demo: AcousticDemoConfig,
    cdt_dds: Arc<PubSub>,
    keys: Option<AcousticKeys>,
    tap: Option<FrameTap>,
    shutdown: CancellationToken,
) -> Result<()> {
    let mut relay = demo.relay();
    relay.tap = tap;
    let settings = SimSettings {
        ocean: demo.ocean,
        ..SimSettings::default()
    };
    let specs: HashMap<String, SimSpec> = demo
        .vehicles
        .into_iter()
        .map(|v| (v.sim.id.clone(), v.sim))
        .collect();
    let start_sim = move |v: &RelayedVehicle, dds: Arc<PubSub>, stop: CancellationToken| {
        let spec = specs.get(&v.id).cloned();
        let settings = settings.clone();
        async move {
            // Every relayed vehicle was made from a demo vehicle, so its spec is there.
            let spec = spec.ok_or_else(|| {
                ConverterError::Config("relayed vehicle missing from the demo".into())
            })?;
            shoal_proxy::run_sim_with(spec, settings, dds, stop)
                .await
                .map_err(ConverterError::from)
        }
    };
    Ok(run_emulated_relay(relay, cdt_dds, keys, start_sim, shutdown).await?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_scenarios_acoustic_vehicle_is_the_demos_own_auv() {
        let s = shoal_scenario::parse(shoal_scenario::shipped("sea-trial").unwrap()).unwrap();
        let demo = AcousticDemoConfig::from_scenario(&s).unwrap();
        let own = AcousticDemoConfig::default();
        assert_eq!(demo.vehicles, own.vehicles);
        assert_eq!(demo.relay_vehicle.as_deref(), Some("usv-1"));
        assert_eq!(
            (
                demo.relay_address,
                demo.relay_latitude_deg,
                demo.relay_longitude_deg
            ),
            (
                own.relay_address,
                own.relay_latitude_deg,
                own.relay_longitude_deg
            )
        );
        let ip_only =
            shoal_scenario::parse(shoal_scenario::shipped("harbour-survey").unwrap()).unwrap();
        assert!(AcousticDemoConfig::from_scenario(&ip_only).is_none());
    }

    /// A scenario's `[acoustic.channel]` and `[environment]` reach the relay's emulated sea
    /// and the demo's vehicles.
    #[test]
    fn the_scenarios_channel_and_ocean_reach_the_demo() {
        let text = shoal_scenario::shipped("acoustic-relay")
            .unwrap()
            .to_owned()
            + "\n[acoustic.channel]\nwind_mps = 15.0\ncentre_khz = 12.0\nbandwidth_khz = 6.0\n\n\
               [environment]\nsurface_temperature_c = 6.0\n";
        let s = shoal_scenario::parse(&text).unwrap();
        let demo = AcousticDemoConfig::from_scenario(&s).unwrap();
        assert_eq!(demo.ocean.surface_temperature_c, Some(6.0));
        let relay = demo.relay();
        assert_eq!(
            (relay.channel.wind_mps, relay.channel.centre_khz),
            (15.0, 12.0)
        );
        assert_eq!(relay.channel, s.acoustic.unwrap().channel);
    }
}
