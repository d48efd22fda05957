//! Frames in the recordings are lossless PNG: what the trainer and `rig dataset check` decode.

/// Encodes an RGB image as PNG with fast compression (still lossless): the camera rate leaves a
/// few milliseconds a frame, and the default compression takes several times longer for a few
/// percent less disk.
pub fn encode(img: &image::RgbImage) -> Result<Vec<u8>, image::ImageError> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(img.as_raw().len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub).write_image(
        img.as_raw(),
        img.width(),
        img.height(),
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

/// Decodes a recorded frame.
pub fn decode(png: &[u8]) -> Result<image::RgbImage, image::ImageError> {
    Ok(image::load_from_memory_with_format(png, image::ImageFormat::Png)?.to_rgb8())
}
