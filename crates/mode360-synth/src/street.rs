//! The street's fixed dimensions and the choice between the regular and the varied layout,
//! shared by the world layout ([`super::world`]), the road markings ([`super::material`]) and
//! the props ([`super::props`]).

/// Half width of the road between the kerbs, metres (two lanes and two parking strips).
pub const ROAD_HALF_WIDTH_M: f64 = 7.5;
/// Lane width, metres; lanes are `[-LANE, 0]` (ego, driving +x) and `[0, LANE]`.
pub const LANE_WIDTH_M: f64 = 4.0;
/// Sidewalk top height above the road, metres.
pub const KERB_HEIGHT_M: f64 = 0.15;

/// How much street layouts vary between world seeds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum StreetStyle {
    /// The same cross-section for every seed (`StreetLayout::regular`).
    #[default]
    Regular,
    /// Widths, setbacks, heights, densities and rig pose drawn per seed
    /// (`StreetLayout::varied`).
    Varied,
    /// A varied street with near clutter along the rig's path: poles, sign posts, bollards,
    /// cones, barriers, fences, trunks, people, cyclists, cars, low walls and branches
    /// from about 0.7 m out (`super::clutter`).
    Cluttered,
}

impl StreetStyle {
    pub fn as_str(self) -> &'static str {
        match self {
            StreetStyle::Regular => "regular",
            StreetStyle::Varied => "varied",
            StreetStyle::Cluttered => "cluttered",
        }
    }
}

/// Half width of a cross street along x, centred in its tile, metres.
pub const CROSS_STREET_HALF_WIDTH_M: f64 = 6.0;
