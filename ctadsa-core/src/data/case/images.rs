//! DSA images: 32-bit float TIFF (exact) and 16-bit greyscale PNG with a stored scale
//! (viewable), plus 8-bit PNG previews.

use std::io::{BufReader, BufWriter, Cursor};
use std::path::Path;

use image::{ImageBuffer, Luma};

use crate::error::{CoreError, Result, read_file, write_file};

/// A single-channel image, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Image {
    /// Checks that every pixel is finite, naming the first bad pixel.
    pub fn check_finite(&self, path: &Path) -> Result<()> {
        if let Some(i) = self.data.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::format(
                path,
                format!(
                    "pixel (column {}, row {}) is {} — images must be finite",
                    i % self.width as usize,
                    i / self.width as usize,
                    self.data[i]
                ),
            ));
        }
        Ok(())
    }

    /// Largest pixel value (0 for an empty image).
    pub fn max(&self) -> f32 {
        self.data.iter().copied().fold(0.0, f32::max)
    }
}

/// Writes a 32-bit float greyscale TIFF.
pub fn write_tiff_f32(path: &Path, image: &Image) -> Result<()> {
    let mut bytes = Vec::new();
    {
        let mut enc = tiff::encoder::TiffEncoder::new(Cursor::new(&mut bytes))
            .map_err(|e| CoreError::format(path, format!("TIFF encoder: {e}")))?;
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(image.width, image.height, &image.data)
            .map_err(|e| CoreError::format(path, format!("TIFF encoding failed: {e}")))?;
    }
    write_file(path, &bytes)
}

/// Reads a greyscale TIFF (32-bit float, or 8/16-bit integer converted to f32).
pub fn read_tiff(path: &Path) -> Result<Image> {
    let bytes = read_file(path)?;
    let mut dec = tiff::decoder::Decoder::new(BufReader::new(Cursor::new(bytes)))
        .map_err(|e| CoreError::format(path, format!("not a readable TIFF: {e}")))?;
    let (width, height) = dec.dimensions().map_err(|e| CoreError::format(path, format!("TIFF dimensions: {e}")))?;
    let data: Vec<f32> = match dec.read_image().map_err(|e| CoreError::format(path, format!("TIFF data: {e}")))? {
        tiff::decoder::DecodingResult::F32(v) => v,
        tiff::decoder::DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        tiff::decoder::DecodingResult::U16(v) => v.into_iter().map(|x| x as f32).collect(),
        tiff::decoder::DecodingResult::U8(v) => v.into_iter().map(|x| x as f32).collect(),
        _ => return Err(CoreError::format(path, "unsupported TIFF sample type (use 32-bit float greyscale)")),
    };
    if data.len() != (width * height) as usize {
        return Err(CoreError::format(
            path,
            format!("TIFF holds {} samples for {width} × {height} pixels (one channel expected)", data.len()),
        ));
    }
    Ok(Image { width, height, data })
}

/// Writes a 16-bit PNG where count `c` means the value `c × scale`; returns `scale`
/// (`max / 65535`, or 1 for an all-zero image). Negative values are clipped to 0.
pub fn write_png16(path: &Path, image: &Image) -> Result<f64> {
    let max = image.max() as f64;
    let scale = if max > 0.0 { max / 65535.0 } else { 1.0 };
    let counts: Vec<u16> =
        image.data.iter().map(|&v| ((v as f64 / scale).round().clamp(0.0, 65535.0)) as u16).collect();
    let buf: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_raw(image.width, image.height, counts)
        .ok_or_else(|| CoreError::invalid("image size does not match its data"))?;
    let mut bytes = Vec::new();
    buf.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| CoreError::format(path, format!("PNG encoding failed: {e}")))?;
    write_file(path, &bytes)?;
    Ok(scale)
}

/// Reads a greyscale PNG; values are `count × scale` with 16-bit counts (8-bit files are
/// expanded to 16 bits, ×257, as the `image` crate does).
pub fn read_png(path: &Path, scale: f64) -> Result<Image> {
    let bytes = read_file(path)?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| CoreError::format(path, format!("not a readable PNG: {e}")))?;
    let g = img.into_luma16();
    let (width, height) = g.dimensions();
    Ok(Image { width, height, data: g.into_raw().into_iter().map(|c| (c as f64 * scale) as f32).collect() })
}

/// Reads an image by extension: `.tif`/`.tiff` exact; `.png` needs `png_scale`.
pub fn read_image(path: &Path, png_scale: Option<f64>) -> Result<Image> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let image = match ext.as_str() {
        "tif" | "tiff" => read_tiff(path)?,
        "png" => {
            let scale = png_scale.ok_or_else(|| {
                CoreError::format(path, "a PNG view needs `png_scale` (value per count) in the case file")
            })?;
            read_png(path, scale)?
        }
        _ => return Err(CoreError::format(path, "unknown image extension (use .tiff or .png)")),
    };
    image.check_finite(path)?;
    Ok(image)
}

/// Writes an 8-bit preview PNG, linearly mapping `[lo, hi]` to `[0, 255]` (`invert` for the
/// usual dark-vessel DSA look).
pub fn write_preview_png(path: &Path, image: &Image, lo: f32, hi: f32, invert: bool) -> Result<()> {
    let span = if hi > lo { hi - lo } else { 1.0 };
    let px: Vec<u8> = image
        .data
        .iter()
        .map(|&v| {
            let t = ((v - lo) / span).clamp(0.0, 1.0);
            let t = if invert { 1.0 - t } else { t };
            (t * 255.0).round() as u8
        })
        .collect();
    write_rgb_or_grey(path, image.width, image.height, px, 1)
}

/// Writes an 8-bit PNG from raw pixels with `channels` (1 grey, 3 RGB).
pub fn write_rgb_or_grey(path: &Path, width: u32, height: u32, pixels: Vec<u8>, channels: u8) -> Result<()> {
    let color = match channels {
        1 => image::ExtendedColorType::L8,
        3 => image::ExtendedColorType::Rgb8,
        _ => return Err(CoreError::invalid("PNG needs 1 or 3 channels")),
    };
    if pixels.len() != (width * height) as usize * channels as usize {
        return Err(CoreError::invalid("PNG pixel buffer does not match its size"));
    }
    let mut bytes = Vec::new();
    {
        let enc = image::codecs::png::PngEncoder::new(BufWriter::new(&mut bytes));
        image::ImageEncoder::write_image(enc, &pixels, width, height, color)
            .map_err(|e| CoreError::format(path, format!("PNG encoding failed: {e}")))?;
    }
    write_file(path, &bytes)
}

/// Value of an arrival map's pixel ([`super::ViewEntry::arrival`]) that no vessel fills.
pub const NO_ARRIVAL: f32 = -1.0;

/// An arrival map binned by `b` in [`bin_image`]'s block layout: each block keeps its earliest
/// frame ([`NO_ARRIVAL`] where no pixel of it fills).
pub fn bin_arrival(map: &Image, b: u32) -> Image {
    if b <= 1 {
        return map.clone();
    }
    let (w, h) = ((map.width / b).max(1), (map.height / b).max(1));
    let mut data = vec![NO_ARRIVAL; (w * h) as usize];
    for r in 0..h {
        for c in 0..w {
            let block = (0..b * b).map(|k| {
                let (rr, cc) = ((r * b + k / b).min(map.height - 1), (c * b + k % b).min(map.width - 1));
                map.data[(rr * map.width + cc) as usize]
            });
            let earliest = block.filter(|&f| f >= 0.0).fold(f32::INFINITY, f32::min);
            if earliest.is_finite() {
                data[(r * w + c) as usize] = earliest;
            }
        }
    }
    Image { width: w, height: h, data }
}

/// An arrival map read robustly: each filled pixel takes the median frame of the filled pixels
/// within `half_px` pixels of it (a square; of an even count, the earlier of the two middle
/// frames), so a frame detected a frame off among its neighbours' gives way to theirs; pixels
/// no vessel fills stay [`NO_ARRIVAL`], and no pixel gets filled. `half_px` 0: the map as it is.
pub fn median_arrival(map: &Image, half_px: u32) -> Image {
    if half_px == 0 {
        return map.clone();
    }
    let (w, h, r) = (map.width as i64, map.height as i64, half_px as i64);
    let mut window = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
    let mut data = map.data.clone();
    for row in 0..h {
        for col in 0..w {
            if map.data[(row * w + col) as usize] < 0.0 {
                continue;
            }
            window.clear();
            for rr in (row - r).max(0)..(row + r + 1).min(h) {
                for cc in (col - r).max(0)..(col + r + 1).min(w) {
                    let f = map.data[(rr * w + cc) as usize];
                    if f >= 0.0 {
                        window.push(f);
                    }
                }
            }
            window.sort_by(f32::total_cmp);
            data[(row * w + col) as usize] = window[(window.len() - 1) / 2];
        }
    }
    Image { width: map.width, height: map.height, data }
}

/// How noisy an arrival map is: the share of its filled pixels whose frame differs from the
/// median of the filled pixels of their 3 × 3 window ([`median_arrival`] with `half_px` 1); 0
/// for a map no vessel fills. A map with one frame along each stretch of vessel changes only
/// where frames meet and vessels cross (1–3 % of the shared BraVa cases' ideal maps); one
/// whose frames were detected a frame off here and there changes wherever they were (with a
/// per-pixel error of 0.5 frames' standard deviation, about 30 %).
pub fn arrival_noise(map: &Image) -> f64 {
    let median = median_arrival(map, 1);
    let filled = map.data.iter().filter(|&&f| f >= 0.0).count();
    let moved = map.data.iter().zip(&median.data).filter(|&(&f, &m)| f >= 0.0 && m != f).count();
    if filled == 0 { 0.0 } else { moved as f64 / filled as f64 }
}

/// Average-pools an image by `b × b` (line integrals keep their units).
pub fn bin_image(img: &Image, b: u32) -> Image {
    if b <= 1 {
        return img.clone();
    }
    let (w, h) = ((img.width / b).max(1), (img.height / b).max(1));
    let mut data = vec![0.0f32; (w * h) as usize];
    for r in 0..h {
        for c in 0..w {
            let mut s = 0.0;
            for dr in 0..b {
                for dc in 0..b {
                    let (rr, cc) = ((r * b + dr).min(img.height - 1), (c * b + dc).min(img.width - 1));
                    s += img.data[(rr * img.width + cc) as usize];
                }
            }
            data[(r * w + c) as usize] = s / (b * b) as f32;
        }
    }
    Image { width: w, height: h, data }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiff_is_exact_and_png16_is_scaled() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let img = Image { width: 3, height: 2, data: vec![0.0, 1.5, 2.25, 1e-7, 3.0, 0.75] };
        write_tiff_f32(&dir.join("a.tiff"), &img).unwrap();
        assert_eq!(read_image(&dir.join("a.tiff"), None).unwrap(), img);
        let scale = write_png16(&dir.join("a.png"), &img).unwrap();
        let back = read_image(&dir.join("a.png"), Some(scale)).unwrap();
        for (a, b) in back.data.iter().zip(&img.data) {
            assert!((a - b).abs() <= 0.5 * scale as f32 + 1e-7);
        }
        assert!(read_image(&dir.join("a.png"), None).unwrap_err().to_string().contains("png_scale"));
        let nan = Image { data: vec![0.0, f32::NAN, 0.0, 0.0, 0.0, 0.0], ..img };
        write_tiff_f32(&dir.join("nan.tiff"), &nan).unwrap();
        let err = read_image(&dir.join("nan.tiff"), None).unwrap_err().to_string();
        assert!(err.contains("nan.tiff") && err.contains("column 1"), "{err}");
    }

    /// A vessel 2 px wide along the rows, frame 4, pixel 8 of it detected as 5; a second vessel,
    /// frame 9, one row below it.
    fn two_vessels_one_pixel_off() -> Image {
        let n = NO_ARRIVAL;
        #[rustfmt::skip]
        let data = vec![
            4.0, 4.0, 4.0, 4.0, 4.0, 4.0,
            4.0, 4.0, 5.0, 4.0, 4.0, 4.0,
            n,   n,   n,   n,   n,   n,
            9.0, 9.0, 9.0, 9.0, 9.0, 9.0,
        ];
        Image { width: 6, height: 4, data }
    }

    /// The median keeps a vessel's frame where one pixel of it was detected a frame off, never
    /// fills a pixel no vessel fills, and leaves a map of one frame per vessel as it is.
    #[test]
    fn median_arrival_outvotes_a_lone_frame_and_fills_nothing() {
        let n = NO_ARRIVAL;
        let map = two_vessels_one_pixel_off();
        assert_eq!(median_arrival(&map, 0), map);
        let median = median_arrival(&map, 1);
        assert_eq!(median.data[8], 4.0, "the lone 5 goes");
        for (i, (&m, &f)) in median.data.iter().zip(&map.data).enumerate() {
            if f == n {
                assert_eq!(m, n, "pixel {i} gets filled");
            } else if i != 8 {
                assert_eq!(m, f, "pixel {i} of a one-frame vessel moves");
            }
        }
    }

    /// The noise share counts the pixels the median moves, of the filled ones only.
    #[test]
    fn arrival_noise_is_the_share_of_filled_pixels_the_median_moves() {
        let n = NO_ARRIVAL;
        let mut map = two_vessels_one_pixel_off();
        assert!((arrival_noise(&map) - 1.0 / 18.0).abs() < 1e-12);
        map.data[8] = 4.0;
        assert_eq!(arrival_noise(&map), 0.0, "one frame per vessel: nothing moves");
        map.data[3] = 6.0;
        map.data[20] = 7.0;
        assert!((arrival_noise(&map) - 2.0 / 18.0).abs() < 1e-12);
        assert_eq!(arrival_noise(&Image { width: 2, height: 1, data: vec![n, n] }), 0.0, "an empty map");
    }
}
