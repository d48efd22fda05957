//! TEMPORARY stub, replaced by the real module.
use image::RgbImage;
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Modality { #[serde(rename = "rgb+marker")] RgbMarker, #[serde(rename = "rgb")] Rgb, #[serde(rename = "marker")] Marker }
impl Modality {
    pub const ALL: [Modality; 3] = [Modality::RgbMarker, Modality::Rgb, Modality::Marker];
    pub fn name(self) -> &'static str { match self { Self::RgbMarker => "rgb+marker", Self::Rgb => "rgb", Self::Marker => "marker" } }
    pub fn paper_name(self) -> &'static str { match self { Self::RgbMarker => "R+M", Self::Rgb => "R", Self::Marker => "M" } }
    pub fn apply(self, img: &RgbImage, _p: &MarkerParams) -> RgbImage { img.clone() }
}
impl std::str::FromStr for Modality { type Err = String; fn from_str(s: &str) -> Result<Self, String> { Self::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| s.to_string()) } }
impl std::fmt::Display for Modality { fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result { f.write_str(self.name()) } }
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MarkerParams { pub dot_radius_px: f32, pub threshold: f32, pub inpaint_radius_px: f32 }
impl MarkerParams { pub fn for_dot_radius(r: f32) -> Self { Self { dot_radius_px: r, ..Default::default() } } }
