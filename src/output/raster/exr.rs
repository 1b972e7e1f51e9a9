//! Multi-band OpenEXR writer on the `exr` crate: one 32-bit float channel per band, named by the band's name
//! (OpenEXR sorts channels by name; readers look them up by name). ZIP-compressed per 16 lines (lossless).

use std::path::Path;

use exr::prelude::*;

use crate::output::{atomic::AtomicFile, OutputError, Result, SpectralImage};

/// Writes `img` to `path` atomically. Band names must be unique and non-empty.
pub fn write_exr(path: &Path, img: &SpectralImage) -> Result<()> {
    img.validate()?;
    let mut names: Vec<&str> = img.bands.iter().map(|b| b.name.as_str()).collect();
    names.sort_unstable();
    if names.iter().any(|n| n.is_empty()) || names.windows(2).any(|w| w[0] == w[1]) {
        return Err(OutputError::invalid("bands", "EXR channel names (band names) must be unique and non-empty"));
    }
    let channels: Vec<AnyChannel<FlatSamples>> = img
        .bands
        .iter()
        .enumerate()
        .map(|(b, band)| AnyChannel::new(band.name.as_str(), FlatSamples::F32(img.band_data(b).to_vec())))
        .collect();
    let layer = Layer::new(
        (img.width, img.height),
        LayerAttributes::named("msnerf"),
        Encoding { compression: Compression::ZIP16, ..Encoding::default() },
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let image = Image::from_layer(layer);
    let (atomic, file) = AtomicFile::create(path)?;
    image.write().to_buffered(std::io::BufWriter::new(file)).map_err(|e| OutputError::write(path, e))?;
    Ok(atomic.commit()?)
}
