//! JPEG materials (docs/FORMAT.md §11): baseline JPEG files indexed without re-encoding
//! ([`index_jpeg`], `nmat index`) and a material's maps encoded as indexed JPEG
//! ([`encode_jpeg`], `nmat encode --codec jpeg`).

mod encode;
mod index;

pub use encode::{
    DEFAULT_QUALITY, JpegEncoded, JpegOptions, Subsampling, encode_jpeg, encode_jpeg_to_rate,
    plan_maps,
};
pub use index::{IndexedJpeg, JpegError, RgbRule, index_jpeg, material_from_jpeg};
