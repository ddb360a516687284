//! Underwater acoustic channel physics for the emulator (docs/acoustic.md#channel-physics).
//!
//! The chain is `SNR = SL − TL − NL`, `Eb/N0 = SNR + 10·log10(B/R)`, BER from the
//! modulation, `PER = 1 − (1 − BER)^bits`. [`ChannelModel::default`] holds the parameters
//! that reproduce the worked example of docs/acoustic.md#packet-error-rate: SL 180 dB,
//! 26 kHz centre, 16 kHz band, practical spreading `k = 1.5`, shipping 0.5, wind 5 m/s,
//! BPSK in Rayleigh fading. With them a 20-byte frame has PER 0.010 at 3.5 km and 0.154 at
//! 5 km at 976 bit/s, 0.136 and 0.90 at 13.9 kbit/s, and is lost for certain at 8 km (see
//! the tests).

use serde::{Deserialize, Serialize};

/// Sound speed in sea water, m/s (Mackenzie 1981); `t` °C, `s` ppt, `d` m.
pub fn sound_speed_mackenzie(t: f64, s: f64, d: f64) -> f64 {
    1448.96 + 4.591 * t - 5.304e-2 * t * t
        + 2.374e-4 * t.powi(3)
        + 1.340 * (s - 35.0)
        + 1.630e-2 * d
        + 1.675e-7 * d * d
        - 1.025e-2 * t * (s - 35.0)
        - 7.139e-13 * t * d.powi(3)
}

/// Absorption, dB/km, at `f_khz` (Thorp; meant for f ≥ 0.4 kHz).
pub fn absorption_thorp(f_khz: f64) -> f64 {
    let f2 = f_khz * f_khz;
    0.11 * f2 / (1.0 + f2) + 44.0 * f2 / (4100.0 + f2) + 2.75e-4 * f2 + 0.003
}

/// Transmission loss, dB: `k·10·log10(d) + α·d_km` with `k` from 1 (cylindrical) to 2
/// (spherical); distances under 1 m count as 1 m.
pub fn transmission_loss(distance_m: f64, f_khz: f64, k: f64) -> f64 {
    let d = distance_m.max(1.0);
    k * 10.0 * d.log10() + absorption_thorp(f_khz) * d / 1000.0
}

/// Ambient noise power spectral density, dB re µPa²/Hz (Wenz-style sum of turbulence,
/// shipping `s` ∈ [0, 1], wind `w` m/s and thermal noise).
pub fn noise_psd(f_khz: f64, shipping: f64, wind_mps: f64) -> f64 {
    let lf = f_khz.log10();
    let turbulence = 17.0 - 30.0 * lf;
    let ships = 40.0 + 20.0 * (shipping - 0.5) + 26.0 * lf - 60.0 * (f_khz + 0.03).log10();
    let wind = 50.0 + 7.5 * wind_mps.max(0.0).sqrt() + 20.0 * lf - 40.0 * (f_khz + 0.4).log10();
    let thermal = -15.0 + 20.0 * lf;
    // Sum in power, not in dB.
    10.0 * [turbulence, ships, wind, thermal]
        .iter()
        .map(|db| 10f64.powf(db / 10.0))
        .sum::<f64>()
        .log10()
}

/// Noise level in a band of `bandwidth_hz` around `f_khz`, dB re µPa (PSD + 10·log10 B).
pub fn noise_level(f_khz: f64, bandwidth_hz: f64, shipping: f64, wind_mps: f64) -> f64 {
    noise_psd(f_khz, shipping, wind_mps) + 10.0 * bandwidth_hz.max(1.0).log10()
}

/// Eb/N0 in dB from SNR over bandwidth `B` at bit rate `R`.
pub fn eb_n0(snr_db: f64, bandwidth_hz: f64, bit_rate: f64) -> f64 {
    snr_db + 10.0 * (bandwidth_hz / bit_rate.max(1e-9)).log10()
}

/// Complementary error function (Numerical Recipes' Chebyshev fit, |rel. error| < 1.2e-7).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// Gaussian tail probability `Q(x) = ½·erfc(x/√2)`.
pub fn q_function(x: f64) -> f64 {
    0.5 * erfc(x / std::f64::consts::SQRT_2)
}

/// Modulation and fading model that maps Eb/N0 to a bit error rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Modulation {
    /// Coherent BPSK in white noise: `Q(√(2γ))`.
    Bpsk,
    /// Non-coherent binary FSK: `½·e^(−γ/2)`.
    NonCoherentFsk,
    /// BPSK in Rayleigh fading: `½(1 − √(γ/(1+γ)))`; the default, because without fading
    /// the link looks perfect until absorption cuts it off
    /// (docs/acoustic.md#packet-error-rate).
    RayleighBpsk,
}

/// Bit error rate for Eb/N0 `ebn0_db` (dB).
pub fn ber(modulation: Modulation, ebn0_db: f64) -> f64 {
    let g = 10f64.powf(ebn0_db / 10.0);
    let b = match modulation {
        Modulation::Bpsk => q_function((2.0 * g).sqrt()),
        Modulation::NonCoherentFsk => 0.5 * (-g / 2.0).exp(),
        Modulation::RayleighBpsk => 0.5 * (1.0 - (g / (1.0 + g)).sqrt()),
    };
    b.clamp(0.0, 0.5)
}

/// Packet error rate of `bits` independent bits at `ber`.
pub fn per(ber: f64, bits: usize) -> f64 {
    let n = i32::try_from(bits).unwrap_or(i32::MAX);
    (1.0 - (1.0 - ber.clamp(0.0, 1.0)).powi(n)).clamp(0.0, 1.0)
}

/// All parameters of the channel between two modems; the defaults reproduce the worked
/// example of docs/acoustic.md#packet-error-rate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ChannelModel {
    /// Source level, dB re µPa at 1 m.
    pub source_level_db: f64,
    /// Carrier centre frequency, kHz.
    pub centre_khz: f64,
    /// Signal bandwidth, kHz.
    pub bandwidth_khz: f64,
    /// Spreading exponent k (1 cylindrical … 2 spherical, 1.5 practical).
    pub spreading_k: f64,
    /// Shipping activity, 0..=1.
    pub shipping: f64,
    /// Wind speed, m/s.
    pub wind_mps: f64,
    /// Water temperature, °C (for sound speed).
    pub temperature_c: f64,
    /// Salinity, ppt (for sound speed).
    pub salinity_ppt: f64,
    /// BER model.
    pub modulation: Modulation,
}

impl Default for ChannelModel {
    fn default() -> Self {
        Self {
            source_level_db: 180.0,
            centre_khz: 26.0,
            bandwidth_khz: 16.0,
            spreading_k: 1.5,
            shipping: 0.5,
            wind_mps: 5.0,
            temperature_c: 10.0,
            salinity_ppt: 35.0,
            modulation: Modulation::RayleighBpsk,
        }
    }
}

impl ChannelModel {
    /// Sound speed at depth `depth_m`, m/s.
    pub fn sound_speed(&self, depth_m: f64) -> f64 {
        sound_speed_mackenzie(self.temperature_c, self.salinity_ppt, depth_m.max(0.0))
    }

    /// Received level at `distance_m` for a source `attenuation_db` below full power, dB re µPa.
    pub fn received_level(&self, distance_m: f64, attenuation_db: f64) -> f64 {
        self.source_level_db
            - attenuation_db
            - transmission_loss(distance_m, self.centre_khz, self.spreading_k)
    }

    /// SNR at `distance_m`, dB.
    pub fn snr(&self, distance_m: f64, attenuation_db: f64) -> f64 {
        self.received_level(distance_m, attenuation_db)
            - noise_level(
                self.centre_khz,
                self.bandwidth_khz * 1000.0,
                self.shipping,
                self.wind_mps,
            )
    }

    /// Packet error rate of a `bits`-bit packet at `bit_rate` over `distance_m`.
    pub fn per(&self, distance_m: f64, bits: usize, bit_rate: f64, attenuation_db: f64) -> f64 {
        let e = eb_n0(
            self.snr(distance_m, attenuation_db),
            self.bandwidth_khz * 1000.0,
            bit_rate,
        );
        per(ber(self.modulation, e), bits)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn mackenzie_reference_value_is_frozen() {
        // docs/acoustic.md#channel-physics: T=10 °C, S=35 ppt, D=100 m → 1491.435 m/s
        // (arlpy agrees).
        assert!((sound_speed_mackenzie(10.0, 35.0, 100.0) - 1491.435).abs() < 5e-4);
    }

    #[test]
    fn thorp_reference_values_are_frozen() {
        assert!((absorption_thorp(10.0) - 1.187).abs() < 5e-4);
        assert!((absorption_thorp(25.0) - 6.105).abs() < 5e-4);
    }

    #[test]
    fn worked_example_is_reproduced_by_the_default_parameters() {
        // docs/acoustic.md#packet-error-rate: 20-byte frame, Rayleigh: 0.01 / 0.15 at
        // 976 bit/s, 0.14 / 0.90 at 13.9 kbit/s.
        let m = ChannelModel::default();
        let p = |d: f64, r: f64| m.per(d, 160, r, 0.0);
        assert!(
            (p(3500.0, 976.0) - 0.01).abs() < 0.002,
            "{}",
            p(3500.0, 976.0)
        );
        assert!(
            (p(5000.0, 976.0) - 0.15).abs() < 0.01,
            "{}",
            p(5000.0, 976.0)
        );
        assert!(
            (p(3500.0, 13_900.0) - 0.14).abs() < 0.01,
            "{}",
            p(3500.0, 13_900.0)
        );
        assert!(
            (p(5000.0, 13_900.0) - 0.90).abs() < 0.01,
            "{}",
            p(5000.0, 13_900.0)
        );
        assert!(p(8000.0, 976.0) > 0.999);
    }

    #[test]
    fn ber_models_behave_at_known_points() {
        // BPSK at 9.6 dB Eb/N0 ≈ 1e-5; Rayleigh falls only as 1/(4γ).
        assert!((ber(Modulation::Bpsk, 9.6) / 1e-5 - 1.0).abs() < 0.1);
        assert!((ber(Modulation::NonCoherentFsk, 0.0) - 0.5 * (-0.5f64).exp()).abs() < 1e-12);
        assert!((ber(Modulation::RayleighBpsk, 30.0) - 1.0 / 4000.0).abs() < 1e-5);
        assert!((q_function(0.0) - 0.5).abs() < 1e-7);
    }

    #[test]
    fn noise_sums_in_power() {
        // At 26 kHz with 5 m/s wind, wind noise dominates (~37–38 dB re µPa²/Hz).
        let n = noise_psd(26.0, 0.5, 5.0);
        assert!((37.0..39.0).contains(&n), "{n}");
    }
}
