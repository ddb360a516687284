//! Environment data aggregated: over a WAN paid by the byte, a vehicle's observations do
//! not cross one by one; per (vehicle, property) and window, one summary does.
//!
//! - [`PropertyAggregate`]: one property's summary over a window (count, min, max, mean,
//!   and the latest value with its time and place).
//! - [`EnvironmentAggregates`]: a vehicle's summaries of one window, as a frame carries
//!   them (kind 6 in `docs/federation.md`).
//! - [`Aggregator`]: the sending side's core, with no network: folds observations into
//!   the current window of their vehicle and hands over the windows that are over.
//!
//! Windows are on the wall clock (their bounds are timestamps a remote reader compares),
//! each vehicle on its own phase of the window length (from a hash of its id): a fleet
//! whose windows all closed at once would leave as one burst every window, which a slow
//! link's buffer holds for seconds with alarms waiting behind it (what the WAN bench
//! found with positions). An observation belongs to the window in which the station took
//! it, not the one of its own timestamp: a vehicle's clock, or an acoustic delay, must not
//! reopen a window already sent.

use std::collections::{BTreeMap, BTreeSet};

use shoal_model::{
    EnvironmentObservation, MAX_NAME_LEN, MAX_TIMESTAMP_MS, MAX_VEHICLE_ID_LEN, MIN_TIMESTAMP_MS,
    StateVector, ValidationError, is_identifier,
};

use crate::config::MAX_ENVIRONMENT_WINDOW_S;

/// Most property summaries one frame carries; a vehicle with more sends several frames.
pub const MAX_PROPERTIES_PER_FRAME: usize = 32;
/// Longest unit, bytes (the model's limit).
pub const MAX_UNIT_LEN: usize = 16;
/// Most (vehicle, property) summaries the sending side holds at once (open windows and
/// closed ones not yet sent); observations of further pairs are dropped and counted.
pub const MAX_AGGREGATES: usize = 10_000;
/// Longest window a frame may span, ms (`environment.window_s` at most).
pub const MAX_WINDOW_MS: i64 = MAX_ENVIRONMENT_WINDOW_S as i64 * 1000;

/// One property's summary over a window.
#[derive(Debug, Clone, PartialEq)]
pub struct PropertyAggregate {
    /// The property, e.g. `sea_water_temperature`.
    pub property: String,
    /// Unit of every value (UCUM code, e.g. `Cel`), at most 16 bytes; may be empty.
    pub unit: String,
    /// Observations summarised, at least 1.
    pub count: u32,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Mean value, in [min, max].
    pub mean: f64,
    /// Value of the latest observation (by its timestamp).
    pub last_value: f64,
    /// Time of the latest observation, ms since the Unix epoch.
    pub last_ms: i64,
    /// Where the latest observation was taken: WGS84 latitude, degrees.
    pub latitude_deg: f64,
    /// Its WGS84 longitude, degrees.
    pub longitude_deg: f64,
    /// Its depth, metres, [0, 11000].
    pub depth_m: f64,
}

/// A vehicle's summaries of one window: what one environment frame carries.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvironmentAggregates {
    /// The vehicle (from the key expression on the wire).
    pub vehicle_id: String,
    /// Start of the window, ms since the Unix epoch (inclusive).
    pub window_start_ms: i64,
    /// End of the window, ms since the Unix epoch (exclusive).
    pub window_end_ms: i64,
    /// One summary per property, each property once, 1..=32 of them.
    pub properties: Vec<PropertyAggregate>,
}

fn bad(field: &'static str, rule: &'static str) -> ValidationError {
    ValidationError::Inconsistent { field, rule }
}

fn finite_in(field: &'static str, value: f64, range: (f64, f64)) -> Result<(), ValidationError> {
    if !value.is_finite() {
        return Err(ValidationError::NotFinite { field });
    }
    if value < range.0 || value > range.1 {
        return Err(ValidationError::OutOfRange {
            field,
            value,
            min: range.0,
            max: range.1,
        });
    }
    Ok(())
}

#[allow(clippy::cast_precision_loss)]
fn timestamp(field: &'static str, ms: i64) -> Result<(), ValidationError> {
    if !(MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS).contains(&ms) {
        return Err(ValidationError::OutOfRange {
            field,
            value: ms as f64,
            min: MIN_TIMESTAMP_MS as f64,
            max: MAX_TIMESTAMP_MS as f64,
        });
    }
    Ok(())
}

impl PropertyAggregate {
    /// Checks the name, the unit and that the numbers are a summary: finite, a count of at
    /// least 1, min ≤ mean ≤ max and min ≤ last ≤ max, the place in the model's ranges.
    pub fn validate(&self) -> Result<(), ValidationError> {
        if !is_identifier(&self.property, MAX_NAME_LEN) {
            return Err(ValidationError::BadText {
                field: "property",
                rule: "must be 1..=64 of [A-Za-z0-9_.-]",
            });
        }
        if self.unit.len() > MAX_UNIT_LEN {
            return Err(ValidationError::BadText {
                field: "unit",
                rule: "too long",
            });
        }
        if self.unit.chars().any(char::is_control) {
            return Err(ValidationError::BadText {
                field: "unit",
                rule: "control characters are not allowed",
            });
        }
        if self.count == 0 {
            return Err(bad("count", "a summary has at least one observation"));
        }
        let any = (f64::MIN, f64::MAX);
        finite_in("min", self.min, any)?;
        finite_in("max", self.max, any)?;
        finite_in("mean", self.mean, any)?;
        finite_in("last_value", self.last_value, any)?;
        if self.min > self.max {
            return Err(bad("min", "must not exceed max"));
        }
        if !(self.min..=self.max).contains(&self.mean) {
            return Err(bad("mean", "must lie in [min, max]"));
        }
        if !(self.min..=self.max).contains(&self.last_value) {
            return Err(bad("last_value", "must lie in [min, max]"));
        }
        timestamp("last_ms", self.last_ms)?;
        finite_in("latitude_deg", self.latitude_deg, StateVector::LATITUDE)?;
        finite_in("longitude_deg", self.longitude_deg, StateVector::LONGITUDE)?;
        finite_in("depth_m", self.depth_m, StateVector::DEPTH)
    }
}

impl EnvironmentAggregates {
    /// Checks the vehicle, the window (start before end, at most an hour, both in the
    /// model's years), 1..=32 properties each named once, and each summary.
    pub fn validate(&self) -> Result<(), ValidationError> {
        if !is_identifier(&self.vehicle_id, MAX_VEHICLE_ID_LEN) {
            return Err(ValidationError::BadText {
                field: "vehicle_id",
                rule: "must be 1..=32 of [A-Za-z0-9_.-]",
            });
        }
        timestamp("window_start_ms", self.window_start_ms)?;
        timestamp("window_end_ms", self.window_end_ms)?;
        let span = self.window_end_ms - self.window_start_ms;
        if span <= 0 || span > MAX_WINDOW_MS {
            return Err(bad(
                "window_start_ms",
                "a window starts before it ends, at most an hour before",
            ));
        }
        if self.properties.is_empty() || self.properties.len() > MAX_PROPERTIES_PER_FRAME {
            return Err(bad("properties", "a frame carries 1..=32 properties"));
        }
        for (i, p) in self.properties.iter().enumerate() {
            p.validate()?;
            // At most 32: quadratic is cheaper than a set.
            if self.properties[..i]
                .iter()
                .any(|q| q.property == p.property)
            {
                return Err(bad("property", "each property once in a frame"));
            }
        }
        Ok(())
    }
}

/// One property's running summary in an open window.
#[derive(Debug, Clone)]
struct Running {
    unit: String,
    count: u64,
    min: f64,
    max: f64,
    /// Plain sum for the mean; when it overflows (values near `f64::MAX`), `mean` below.
    sum: f64,
    /// Incremental mean, which never overflows.
    mean: f64,
    last_value: f64,
    last_ms: i64,
    latitude_deg: f64,
    longitude_deg: f64,
    depth_m: f64,
}

impl Running {
    fn new(o: &EnvironmentObservation) -> Self {
        Self {
            unit: o.unit.clone(),
            count: 1,
            min: o.value,
            max: o.value,
            sum: o.value,
            mean: o.value,
            last_value: o.value,
            last_ms: o.timestamp_ms,
            latitude_deg: o.latitude_deg,
            longitude_deg: o.longitude_deg,
            depth_m: o.depth_m,
        }
    }

    #[allow(clippy::cast_precision_loss)]
    fn fold(&mut self, o: &EnvironmentObservation) {
        let x = o.value;
        self.count = self.count.saturating_add(1);
        self.min = self.min.min(x);
        self.max = self.max.max(x);
        self.sum += x;
        // Each term at most f64::MAX / 2 in size (count ≥ 2): no overflow.
        let n = self.count as f64;
        self.mean += x / n - self.mean / n;
        // The latest by the observation's own time (a late one does not replace it); the
        // later taken wins a tie.
        if o.timestamp_ms >= self.last_ms {
            self.last_value = x;
            self.last_ms = o.timestamp_ms;
            self.latitude_deg = o.latitude_deg;
            self.longitude_deg = o.longitude_deg;
            self.depth_m = o.depth_m;
        }
    }

    #[allow(clippy::cast_precision_loss)]
    fn finish(self, property: String) -> PropertyAggregate {
        let mean = if self.sum.is_finite() {
            self.sum / self.count as f64
        } else {
            self.mean
        };
        // Rounding can take a mean of equal values an ulp past them; the frame promises
        // min ≤ mean ≤ max, and a decoder refuses anything else.
        let mean = if mean.is_finite() {
            mean.clamp(self.min, self.max)
        } else {
            self.last_value
        };
        PropertyAggregate {
            property,
            unit: self.unit,
            count: u32::try_from(self.count).unwrap_or(u32::MAX),
            min: self.min,
            max: self.max,
            mean,
            last_value: self.last_value,
            last_ms: self.last_ms,
            latitude_deg: self.latitude_deg,
            longitude_deg: self.longitude_deg,
            depth_m: self.depth_m,
        }
    }
}

/// A vehicle's open window.
#[derive(Debug, Clone)]
struct Window {
    start_ms: i64,
    end_ms: i64,
    properties: BTreeMap<String, Running>,
}

/// What became of an observation offered to the [`Aggregator`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Observed {
    /// Folded into its vehicle's current window.
    Taken,
    /// Its property is not in `environment.properties`.
    NotListed,
    /// A new (vehicle, property) while [`MAX_AGGREGATES`] are held: dropped.
    Dropped,
    /// Its unit is not the one of the property's summary in this window: dropped (a
    /// summary of values in two units would be meaningless).
    UnitMismatch,
}

/// Folds (validated) observations into per-vehicle windows and releases the windows that
/// are over. Times are ms since the Unix epoch (the wall clock).
#[derive(Debug)]
pub struct Aggregator {
    window_ms: i64,
    /// Properties that cross; empty: all.
    properties: BTreeSet<String>,
    max_aggregates: usize,
    open: BTreeMap<String, Window>,
    /// Windows found over when their vehicle's next observation came, to send at the next
    /// [`Aggregator::due`].
    closed: Vec<EnvironmentAggregates>,
    /// Summaries in `open` and `closed`.
    held: usize,
}

impl Aggregator {
    /// An aggregator with windows of `window_ms`, letting `properties` through (all when
    /// empty), holding at most `max_aggregates` summaries.
    pub fn new(window_ms: i64, properties: &[String], max_aggregates: usize) -> Self {
        Self {
            window_ms: window_ms.max(1),
            properties: properties.iter().cloned().collect(),
            max_aggregates,
            open: BTreeMap::new(),
            closed: Vec::new(),
            held: 0,
        }
    }

    /// The window of `vehicle` that contains `now_ms`: `[start, start + window)`, on the
    /// vehicle's phase.
    pub fn window_of(&self, vehicle: &str, now_ms: i64) -> (i64, i64) {
        let w = self.window_ms;
        let phase = crate::outbound::phase(vehicle, w);
        let start = (now_ms - phase).div_euclid(w) * w + phase;
        (start, start + w)
    }

    /// Takes an observation (validated by the caller) that the station took at `now_ms`.
    pub fn observe(&mut self, o: &EnvironmentObservation, now_ms: i64) -> Observed {
        if !self.properties.is_empty() && !self.properties.contains(&o.property) {
            return Observed::NotListed;
        }
        if self
            .open
            .get(&o.vehicle_id)
            .is_some_and(|w| now_ms >= w.end_ms)
        {
            self.close(&o.vehicle_id);
        }
        if !self.open.contains_key(&o.vehicle_id) {
            if self.held >= self.max_aggregates {
                return Observed::Dropped;
            }
            let (start_ms, end_ms) = self.window_of(&o.vehicle_id, now_ms);
            self.open.insert(
                o.vehicle_id.clone(),
                Window {
                    start_ms,
                    end_ms,
                    properties: BTreeMap::new(),
                },
            );
        }
        let Some(window) = self.open.get_mut(&o.vehicle_id) else {
            return Observed::Dropped;
        };
        match window.properties.get_mut(&o.property) {
            Some(running) if running.unit != o.unit => Observed::UnitMismatch,
            Some(running) => {
                running.fold(o);
                Observed::Taken
            }
            None if self.held >= self.max_aggregates => Observed::Dropped,
            None => {
                window
                    .properties
                    .insert(o.property.clone(), Running::new(o));
                self.held += 1;
                Observed::Taken
            }
        }
    }

    /// The windows over at `now_ms`, each vehicle's summaries split into frames of at most
    /// [`MAX_PROPERTIES_PER_FRAME`], properties in name order. They are forgotten here.
    pub fn due(&mut self, now_ms: i64) -> Vec<EnvironmentAggregates> {
        let over: Vec<String> = self
            .open
            .iter()
            .filter(|(_, w)| now_ms >= w.end_ms)
            .map(|(v, _)| v.clone())
            .collect();
        for vehicle in over {
            self.close(&vehicle);
        }
        let closed = std::mem::take(&mut self.closed);
        self.held = self.open.values().map(|w| w.properties.len()).sum();
        closed
    }

    /// Summaries held now (open windows and closed ones not yet taken by `due`).
    pub fn held(&self) -> usize {
        self.held
    }

    /// Moves a vehicle's window to `closed`, as frames.
    fn close(&mut self, vehicle: &str) {
        let Some(window) = self.open.remove(vehicle) else {
            return;
        };
        let mut properties = window.properties.into_iter().peekable();
        while properties.peek().is_some() {
            let frame: Vec<PropertyAggregate> = properties
                .by_ref()
                .take(MAX_PROPERTIES_PER_FRAME)
                .map(|(name, running)| running.finish(name))
                .collect();
            self.closed.push(EnvironmentAggregates {
                vehicle_id: vehicle.to_string(),
                window_start_ms: window.start_ms,
                window_end_ms: window.end_ms,
                properties: frame,
            });
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Noon on 2023-11-14 UTC, on a whole minute.
    pub(crate) const T0: i64 = 1_699_963_200_000;

    /// An observation of `property` by `vehicle`, value `value`, taken at `ms`.
    pub(crate) fn obs(
        vehicle: &str,
        property: &str,
        value: f64,
        ms: i64,
    ) -> EnvironmentObservation {
        EnvironmentObservation {
            vehicle_id: vehicle.into(),
            property: property.into(),
            timestamp_ms: ms,
            value,
            unit: "Cel".into(),
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.4,
        }
    }

    /// A valid summary of `property`.
    pub(crate) fn aggregate(property: &str) -> PropertyAggregate {
        PropertyAggregate {
            property: property.into(),
            unit: "Cel".into(),
            count: 3,
            min: 12.5,
            max: 14.25,
            mean: 13.0,
            last_value: 14.25,
            last_ms: T0 + 59_000,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.4,
        }
    }

    /// A vehicle's valid window of one minute with these properties' summaries.
    pub(crate) fn aggregates(vehicle: &str, properties: &[&str]) -> EnvironmentAggregates {
        EnvironmentAggregates {
            vehicle_id: vehicle.into(),
            window_start_ms: T0,
            window_end_ms: T0 + 60_000,
            properties: properties.iter().map(|p| aggregate(p)).collect(),
        }
    }

    #[test]
    fn a_window_summarises_each_property_and_is_released_when_over() {
        let mut a = Aggregator::new(60_000, &[], 100);
        let (start, end) = a.window_of("auv-1", T0);
        assert!(start <= T0 && T0 < end && end - start == 60_000);
        for (value, ms) in [(14.0, 3), (12.0, 1), (13.0, 2)] {
            assert_eq!(
                a.observe(&obs("auv-1", "t", value, T0 + ms), T0),
                Observed::Taken
            );
        }
        let mut s = obs("auv-1", "s", 38.0, T0);
        s.unit = "[ppth]".into();
        assert_eq!(a.observe(&s, T0 + 1), Observed::Taken);
        assert_eq!(a.held(), 2);
        assert!(a.due(end - 1).is_empty());
        let frames = a.due(end);
        assert_eq!(frames.len(), 1);
        let f = &frames[0];
        assert_eq!((f.window_start_ms, f.window_end_ms), (start, end));
        assert_eq!(f.validate(), Ok(()));
        // In name order.
        let names: Vec<&str> = f.properties.iter().map(|p| p.property.as_str()).collect();
        assert_eq!(names, ["s", "t"]);
        let t = &f.properties[1];
        assert_eq!((t.count, t.min, t.max, t.mean), (3, 12.0, 14.0, 13.0));
        // The latest by its own time, not the last taken.
        assert_eq!((t.last_value, t.last_ms), (14.0, T0 + 3));
        assert_eq!(f.properties[0].unit, "[ppth]");
        // Released once, then forgotten.
        assert!(a.due(end + 60_000).is_empty());
        assert_eq!(a.held(), 0);
    }

    #[test]
    fn an_observation_after_the_end_starts_the_next_window() {
        let mut a = Aggregator::new(10_000, &[], 100);
        let (_, end) = a.window_of("auv-1", T0);
        a.observe(&obs("auv-1", "t", 1.0, T0), T0);
        // Taken after the end but before the sender looked: the next window's.
        a.observe(&obs("auv-1", "t", 5.0, T0), end);
        let frames = a.due(end + 10_000);
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[0].window_end_ms, end);
        assert_eq!(frames[0].properties[0].max, 1.0);
        assert_eq!(frames[1].window_start_ms, end);
        assert_eq!(frames[1].properties[0].min, 5.0);
    }

    #[test]
    fn vehicles_close_their_windows_on_their_own_phase() {
        let a = Aggregator::new(60_000, &[], 100);
        let ends: BTreeSet<i64> = (0..50)
            .map(|i| a.window_of(&format!("auv-{i}"), T0).1)
            .collect();
        // Not one burst: 50 vehicles close at (almost) 50 different times.
        assert!(ends.len() > 40, "{} distinct ends", ends.len());
    }

    #[test]
    fn only_listed_properties_are_taken() {
        let mut a = Aggregator::new(60_000, &["t".to_string()], 100);
        assert_eq!(a.observe(&obs("v", "t", 1.0, T0), T0), Observed::Taken);
        assert_eq!(a.observe(&obs("v", "s", 1.0, T0), T0), Observed::NotListed);
    }

    #[test]
    fn new_pairs_past_the_bound_are_dropped_and_known_ones_still_taken() {
        let mut a = Aggregator::new(60_000, &[], 2);
        assert_eq!(a.observe(&obs("v", "a", 1.0, T0), T0), Observed::Taken);
        assert_eq!(a.observe(&obs("v", "b", 1.0, T0), T0), Observed::Taken);
        assert_eq!(a.observe(&obs("v", "c", 1.0, T0), T0), Observed::Dropped);
        assert_eq!(a.observe(&obs("w", "a", 1.0, T0), T0), Observed::Dropped);
        assert_eq!(a.observe(&obs("v", "a", 2.0, T0), T0), Observed::Taken);
        // Sent: room again.
        a.due(T0 + 60_000 * 2);
        assert_eq!(
            a.observe(&obs("w", "a", 1.0, T0), T0 + 120_000),
            Observed::Taken
        );
    }

    #[test]
    fn a_unit_change_within_a_window_is_not_mixed_in() {
        let mut a = Aggregator::new(60_000, &[], 10);
        a.observe(&obs("v", "t", 10.0, T0), T0);
        let mut kelvin = obs("v", "t", 283.15, T0);
        kelvin.unit = "K".into();
        assert_eq!(a.observe(&kelvin, T0), Observed::UnitMismatch);
        let frames = a.due(T0 + 120_000);
        assert_eq!(frames[0].properties[0].max, 10.0);
    }

    #[test]
    fn more_than_32_properties_are_split_into_frames() {
        let mut a = Aggregator::new(60_000, &[], 100);
        for i in 0..70 {
            a.observe(&obs("v", &format!("p{i:02}"), 1.0, T0), T0);
        }
        let frames = a.due(T0 + 120_000);
        let sizes: Vec<usize> = frames.iter().map(|f| f.properties.len()).collect();
        assert_eq!(sizes, [32, 32, 6]);
        assert!(frames.iter().all(|f| f.validate().is_ok()));
    }

    #[test]
    fn the_mean_of_extreme_values_stays_finite_and_within_min_and_max() {
        let mut a = Aggregator::new(60_000, &[], 10);
        for x in [f64::MAX, f64::MAX, -f64::MAX, 0.1, 0.1] {
            a.observe(&obs("v", "x", x, T0), T0);
        }
        for _ in 0..7 {
            a.observe(&obs("v", "y", 0.1, T0), T0);
        }
        let f = &a.due(T0 + 120_000)[0];
        assert_eq!(f.validate(), Ok(()));
        let x = &f.properties[0];
        assert!(x.mean.is_finite() && x.mean >= x.min && x.mean <= x.max);
        // Seven times 0.1 sums to 0.7000000000000001: the mean is clamped to 0.1.
        assert_eq!(f.properties[1].mean, 0.1);
    }

    #[test]
    fn a_summary_that_is_not_one_is_invalid() {
        let check = |edit: fn(&mut PropertyAggregate)| {
            let mut p = aggregate("t");
            edit(&mut p);
            p.validate().unwrap_err().reason().to_string()
        };
        assert_eq!(check(|p| p.count = 0), "inconsistent:count");
        assert_eq!(check(|p| p.min = 15.0), "inconsistent:min");
        assert_eq!(check(|p| p.mean = 20.0), "inconsistent:mean");
        assert_eq!(check(|p| p.last_value = 1.0), "inconsistent:last_value");
        assert_eq!(check(|p| p.max = f64::NAN), "not_finite:max");
        assert_eq!(check(|p| p.property = "a b".into()), "bad_text:property");
        assert_eq!(check(|p| p.unit = "\n".into()), "bad_text:unit");
        assert_eq!(check(|p| p.depth_m = -1.0), "out_of_range:depth_m");
        let mut twice = aggregates("v", &["t", "t"]);
        assert_eq!(
            twice.validate().unwrap_err().reason().to_string(),
            "inconsistent:property"
        );
        twice.properties.clear();
        assert_eq!(
            twice.validate().unwrap_err().reason().to_string(),
            "inconsistent:properties"
        );
        let mut w = aggregates("v", &["t"]);
        w.window_end_ms = w.window_start_ms;
        assert_eq!(
            w.validate().unwrap_err().reason().to_string(),
            "inconsistent:window_start_ms"
        );
    }
}
