//! Frame images: the lossless PNG the recorder encodes raw-pixel frames to, and the decoding
//! of either stored format (PNG, or an MJPEG camera's own JPEG) for the trainer, the export and
//! `rig dataset check`.

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

/// Decodes a recorded PNG frame.
pub fn decode(png: &[u8]) -> Result<image::RgbImage, image::ImageError> {
    decode_as(super::channels::ImageFormat::Png, png)
}

/// Decodes a recorded frame in its stored format.
pub fn decode_as(
    format: super::channels::ImageFormat,
    bytes: &[u8],
) -> Result<image::RgbImage, image::ImageError> {
    let f = match format {
        super::channels::ImageFormat::Png => image::ImageFormat::Png,
        super::channels::ImageFormat::Jpeg => image::ImageFormat::Jpeg,
    };
    Ok(image::load_from_memory_with_format(bytes, f)?.to_rgb8())
}
