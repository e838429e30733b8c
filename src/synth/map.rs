//! The map raster the `map` table names: a grayscale PNG at the devkit's native 0.1 m per pixel, in
//! the form `lyft_dataset_sdk`'s `MapMask` reads (monochrome, foreground 255): 255 on the
//! drivable surface and the sidewalks and driveways, 120 on the planting strips, 0 where there is
//! no map. Pixel (0, 0) is the top-left corner and global (0, 0) the bottom-left corner, as
//! `MapMask.transform_matrix` expects. Lane paint is not drawn (it is drivable surface).

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use nalgebra::Point3;
use rayon::prelude::*;

use super::scene::{Town, MAP_HALF_WIDTH, MAP_RESOLUTION};
use super::shapes::materials;
use super::street::Ground;

const BACKGROUND: u8 = 0;
const SURFACE: u8 = 255;
const STRIP: u8 = 120;

fn value(ground: &Ground, x: f64, y: f64) -> u8 {
    let l = &ground.layout;
    let ay = y.abs();
    if ay < l.curb() {
        SURFACE
    } else if ay < l.sidewalk_outer() {
        if ground.material(x, y) == materials::CONCRETE {
            SURFACE
        } else {
            STRIP
        }
    } else {
        BACKGROUND
    }
}

/// Renders the raster as tightly packed rows of 8-bit gray.
pub(crate) fn render(town: &Town) -> (u32, u32, Vec<u8>) {
    let (w, h) = (town.map.width_px, town.map.height_px);
    let inverses: Vec<_> = town.street_poses.iter().map(|p| p.inverse()).collect();
    let mut buf = vec![BACKGROUND; w as usize * h as usize];
    buf.par_chunks_mut(w as usize).enumerate().for_each(|(py, row)| {
        let gy = (f64::from(h) - py as f64) * MAP_RESOLUTION;
        for (px, pixel) in row.iter_mut().enumerate() {
            let gx = px as f64 * MAP_RESOLUTION;
            for (s, inv) in inverses.iter().enumerate() {
                let p = inv.transform_point(&Point3::new(gx, gy, 0.0));
                let (x_lo, x_hi) = town.map_x_range[s];
                if p.x >= x_lo && p.x <= x_hi && p.y.abs() <= MAP_HALF_WIDTH {
                    *pixel = (*pixel).max(value(&town.streets[s].ground, p.x, p.y));
                }
            }
        }
    });
    (w, h, buf)
}

/// Encodes gray rows as a PNG (deterministic for the same pixels).
pub(crate) fn encode_png(w: u32, h: u32, gray: &[u8]) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub).write_image(
        gray,
        w,
        h,
        ExtendedColorType::L8,
    )?;
    Ok(out)
}
