//! The chart scenario files are checked against: Natural Earth's land (1:10 m, public
//! domain) around Trondheimsfjord, the same the console draws. Inside its box a position
//! on land is refused; outside it there is no land to check against.

use std::sync::OnceLock;

use shoal_model::GeoPoint;

/// The console's shipped coastline (GeoJSON: one feature, a clipped land `MultiPolygon`
/// with its `bbox` as a property).
const LAND: &str = include_str!("../../shoal-console/web/src/data/coastline.geojson");

/// Land polygons' rings and the box they cover.
struct Chart {
    /// West, south, east, north, degrees.
    bbox: [f64; 4],
    rings: Vec<Vec<GeoPoint>>,
}

fn chart() -> &'static Chart {
    static CHART: OnceLock<Chart> = OnceLock::new();
    CHART.get_or_init(|| {
        parse(LAND).unwrap_or(Chart {
            bbox: [0.0; 4],
            rings: Vec::new(),
        })
    })
}

fn parse(text: &str) -> Option<Chart> {
    let doc: serde_json::Value = serde_json::from_str(text).ok()?;
    let feature = doc.get("features")?.get(0)?;
    let bbox: Vec<f64> =
        serde_json::from_value(feature.get("properties")?.get("bbox")?.clone()).ok()?;
    let polygons: Vec<Vec<Vec<[f64; 2]>>> =
        serde_json::from_value(feature.get("geometry")?.get("coordinates")?.clone()).ok()?;
    // GeoJSON positions are [longitude, latitude].
    let rings = polygons
        .into_iter()
        .flatten()
        .map(|ring| {
            ring.into_iter()
                .map(|[lon, lat]| GeoPoint {
                    latitude_deg: lat,
                    longitude_deg: lon,
                })
                .collect()
        })
        .collect();
    Some(Chart {
        bbox: bbox.try_into().ok()?,
        rings,
    })
}

/// Whether a position is on land: `None` outside the chart's box (no data there).
pub fn on_land(latitude_deg: f64, longitude_deg: f64) -> Option<bool> {
    let c = chart();
    let [west, south, east, north] = c.bbox;
    if !(west..=east).contains(&longitude_deg) || !(south..=north).contains(&latitude_deg) {
        return None;
    }
    // Even-odd over every ring (outer rings and holes alike).
    let containing = c
        .rings
        .iter()
        .filter(|r| shoal_model::geo::inside(r, latitude_deg, longitude_deg))
        .count();
    Some(containing % 2 == 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_city_is_land_the_fjord_is_sea_and_elsewhere_is_unknown() {
        assert!(!chart().rings.is_empty(), "the shipped chart parses");
        // Trondheim's centre, and the fjord off Munkholmen where the scenarios sail.
        assert_eq!(on_land(63.43, 10.395), Some(true));
        assert_eq!(on_land(63.465, 10.37), Some(false));
        // Outside the chart's box: no data, so no verdict.
        assert_eq!(on_land(43.0, 5.0), None);
        assert_eq!(on_land(63.0, 10.0), None);
    }
}
