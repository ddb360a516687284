//! The chart scenario files are checked against: Natural Earth's land (1:10 m, public
//! domain) around Trondheimsfjord, the same the console draws. Inside its box a position
//! on land is refused; outside it there is no land to check against.

use std::sync::OnceLock;

/// The console's shipped coastline (GeoJSON: one feature, a clipped land `MultiPolygon`
/// with its `bbox` as a property).
const LAND: &str = include_str!("../../shoal-console/web/src/data/coastline.geojson");

/// Land polygons' rings (lon, lat) and the box they cover.
struct Chart {
    /// West, south, east, north, degrees.
    bbox: [f64; 4],
    rings: Vec<Vec<[f64; 2]>>,
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
    Some(Chart {
        bbox: bbox.try_into().ok()?,
        rings: polygons.into_iter().flatten().collect(),
    })
}

/// Whether a position is on land: `None` outside the chart's box (no data there).
pub fn on_land(latitude_deg: f64, longitude_deg: f64) -> Option<bool> {
    let c = chart();
    let [west, south, east, north] = c.bbox;
    if !(west..=east).contains(&longitude_deg) || !(south..=north).contains(&latitude_deg) {
        return None;
    }
    // Even-odd rule over every ring (outer rings and holes alike): a ray east from the
    // point crosses land's boundary an odd number of times when it starts on land.
    let mut inside = false;
    for ring in &c.rings {
        for (a, b) in ring.iter().zip(ring.iter().cycle().skip(1)) {
            let ([x1, y1], [x2, y2]) = (*a, *b);
            if (y1 > latitude_deg) != (y2 > latitude_deg) {
                let x = x1 + (latitude_deg - y1) * (x2 - x1) / (y2 - y1);
                if longitude_deg < x {
                    inside = !inside;
                }
            }
        }
    }
    Some(inside)
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
