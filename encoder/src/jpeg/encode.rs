//! A material's maps as indexed baseline JPEG: every map at every mip is compressed by the
//! `jpeg-encoder` crate (pure Rust, baseline, the quality scale of the IJG library) and indexed by
//! [`index_jpeg`], so the file decodes to exactly what any JPEG decoder with the integer IDCT
//! makes of those files. docs/ENCODING.md, "JPEG".

use jpeg_encoder::{ColorType, Encoder, QuantizationTableType, SamplingFactor};
use nmat_core::{AddressMode, ColorSpace, Container, Error, Field, JpegMap, JpegMaterialSpec};

use super::index::{IndexedJpeg, index_jpeg, position_or_push};
use crate::error::{EncodeError, EncodeOption};
use crate::metrics::ChainQuality;
use crate::{Storage, TextureSet, as_stored, channel_specs, packed_form, source_maps};

/// The quality `nmat encode --codec jpeg` uses when given neither a quality nor a rate.
pub const DEFAULT_QUALITY: u8 = 85;

/// Huffman tables a material may hold (docs/FORMAT.md §11.1).
const MAX_HUFFMAN_TABLES: usize = 32;

/// Chroma resolution of colour maps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Subsampling {
    /// Chroma at full resolution.
    S444,
    /// Chroma at half width.
    S422,
    /// Chroma at half width and half height: what photographs and the JPEG-texture paper use.
    #[default]
    S420,
}

impl Subsampling {
    /// Luma samples per chroma sample, across and down.
    pub fn luma_per_chroma(self) -> (u8, u8) {
        match self {
            Subsampling::S444 => (1, 1),
            Subsampling::S422 => (2, 1),
            Subsampling::S420 => (2, 2),
        }
    }
}

#[derive(Clone, Debug)]
pub struct JpegOptions {
    /// 1 ..= 100 on the IJG scale (`cjpeg -quality`): the Annex K tables scaled by
    /// `5000 / q` below 50 and `200 − 2q` from 50, each entry clamped to 1 ..= 255.
    pub quality: u8,
    /// Of colour maps (three sRGB channels: albedo, emissive, specular colour). Other
    /// three-channel maps (normals) are coded 4:4:4 with the luma table for every component:
    /// their channels are data, not colour the eye sees at half resolution.
    pub subsampling: Subsampling,
    pub address_mode: AddressMode,
    /// Whether the file keeps its streams' index (fixed-rate) or leaves it to be rebuilt when
    /// the file is opened (packed, the default: smaller by the index and DC values).
    pub storage: Storage,
}

impl Default for JpegOptions {
    fn default() -> Self {
        JpegOptions {
            quality: DEFAULT_QUALITY,
            subsampling: Subsampling::default(),
            address_mode: AddressMode::Wrap,
            storage: Storage::default(),
        }
    }
}

/// The result of a JPEG encode.
pub struct JpegEncoded {
    /// The fixed-rate file (streams with their index): what decoders hold in memory.
    pub bytes: Vec<u8>,
    /// The same without the index, when [`Storage::Packed`] was asked for.
    pub packed: Option<Vec<u8>>,
    /// The quality the streams were coded at (the one searched for by [`encode_jpeg_to_rate`]).
    pub jpeg_quality: u8,
    /// Whole-chain quality of the decode against the source mip chain.
    pub quality: ChainQuality,
}

/// One JPEG map of a material and how its channels are coded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PlannedMap {
    map: JpegMap,
    /// Luma and chroma tables (a colour map); else the luma table for every component.
    colour: bool,
}

/// The JPEG maps of `set`, in channel order: the first three channels of a source map of three
/// or more as one YCbCr map (subsampled if they are colour), every other channel as a gray map.
pub fn plan_maps(set: &TextureSet, subsampling: Subsampling) -> Vec<JpegMap> {
    plan(set, subsampling).into_iter().map(|p| p.map).collect()
}

fn plan(set: &TextureSet, subsampling: Subsampling) -> Vec<PlannedMap> {
    let mut maps = Vec::new();
    let mut c = 0;
    while c < set.channel_count() {
        let source = set.maps.iter().find(|m| m.first_channel == c && m.channel_count >= 3);
        let map = |channel_count, (luma_h, luma_v)| JpegMap {
            first_channel: c as u8,
            channel_count,
            luma_h,
            luma_v,
        };
        match source {
            Some(s) => {
                let colour = s.role.color_space() == ColorSpace::Srgb;
                let sampling = if colour { subsampling.luma_per_chroma() } else { (1, 1) };
                maps.push(PlannedMap { map: map(3, sampling), colour });
                c += 3;
            }
            None => {
                maps.push(PlannedMap { map: map(1, (1, 1)), colour: false });
                c += 1;
            }
        }
    }
    maps
}

/// Encodes every map of `set` at every mip at `options.quality` and measures the result.
pub fn encode_jpeg(set: &TextureSet, options: &JpegOptions) -> Result<JpegEncoded, EncodeError> {
    if !(1..=100).contains(&options.quality) {
        return Err(EncodeError::BadOption {
            option: EncodeOption::Quality,
            value: options.quality.to_string(),
            reason: "must be between 1 and 100",
        });
    }
    let bytes = jpeg_bytes(set, options)?;
    let (packed, quality) = as_stored(&bytes, set, options.storage)?;
    Ok(JpegEncoded { bytes, packed, jpeg_quality: options.quality, quality })
}

impl JpegEncoded {
    /// The file to write: packed if there is a packed form, else fixed-rate.
    pub fn file(&self) -> &[u8] {
        self.packed.as_deref().unwrap_or(&self.bytes)
    }
}

/// [`encode_jpeg`] at the highest quality whose file, as stored (`options.storage`), is at most
/// `bppc` bits per pixel per channel of the channels that vary (bisected over 1 ..= 100;
/// quality 1 if even that is larger: a fixed-rate file's index and DC values alone cost 0.21
/// bits per pixel of a 4:2:0 map and 0.47 of a gray one).
pub fn encode_jpeg_to_rate(
    set: &TextureSet,
    bppc: f64,
    options: &JpegOptions,
) -> Result<JpegEncoded, EncodeError> {
    if !(bppc.is_finite() && bppc > 0.0) {
        return Err(EncodeError::BadOption {
            option: EncodeOption::Bppc,
            value: bppc.to_string(),
            reason: "must be a positive number",
        });
    }
    let fits = |quality: u8| -> Result<bool, EncodeError> {
        match jpeg_bytes(set, &JpegOptions { quality, ..options.clone() }) {
            Ok(bytes) => {
                let stored = packed_form(&bytes, options.storage)?.map_or(bytes.len(), |p| p.len());
                Ok(Container::parse(&bytes)?.bppc_of(stored) <= bppc)
            }
            // Too many bits between two indexed MCUs: a lower quality is needed anyway.
            Err(EncodeError::BadOption { option: EncodeOption::Quality, .. }) => Ok(false),
            Err(e) => Err(e),
        }
    };
    let quality = if fits(100)? {
        100
    } else if !fits(1)? {
        1
    } else {
        // fits(lo) and not fits(hi).
        let (mut lo, mut hi) = (1u8, 100u8);
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if fits(mid)? {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    };
    encode_jpeg(set, &JpegOptions { quality, ..options.clone() })
}

/// The `.nmat` file of `set` as JPEG streams at `options.quality`.
fn jpeg_bytes(set: &TextureSet, options: &JpegOptions) -> Result<Vec<u8>, EncodeError> {
    let plan = plan(set, options.subsampling);
    // Optimized Huffman tables for each gray map's mip 0 (where most of its bits are) while the
    // material's pool of tables has room; the smaller mips and colour maps use the Annex K
    // tables (`jpeg-encoder` optimizes colour only in one scan per component, which an index
    // of whole MCUs cannot use).
    let gray = plan.iter().filter(|p| p.map.channel_count == 1).count();
    let optimize = 2 * gray + 4 <= MAX_HUFFMAN_TABLES;
    let (mut quant_tables, mut huffman_tables, mut streams) = (Vec::new(), Vec::new(), Vec::new());
    for p in &plan {
        for mip in 0..set.mips.len() {
            let indexed = encode_image(
                set,
                mip,
                p,
                options.quality,
                optimize && mip == 0 && p.map.channel_count == 1,
            )?;
            let mut stream = indexed.stream.clone();
            for k in 0..usize::from(p.map.channel_count) {
                let (q, dc, ac) = (stream.quant[k], stream.dc[k], stream.ac[k]);
                let table = |t: u8| usize::from(t);
                stream.quant[k] = position_or_push(&mut quant_tables, indexed.quant[table(q)]);
                stream.dc[k] =
                    position_or_push(&mut huffman_tables, indexed.huffman[table(dc)].clone());
                stream.ac[k] =
                    position_or_push(&mut huffman_tables, indexed.huffman[table(ac)].clone());
            }
            streams.push(stream);
        }
    }
    let spec = JpegMaterialSpec {
        width: set.width,
        height: set.height,
        mip_count: set.mips.len() as u8,
        address_mode: options.address_mode,
        channels: channel_specs(set),
        maps: plan.iter().map(|p| p.map).collect(),
        quant_tables,
        huffman_tables,
        streams,
        optional_sections: vec![(source_maps::SECTION_KIND, source_maps::encode(&set.maps))],
    };
    spec.to_bytes().map_err(|e| match e {
        Error::LimitExceeded { field: Field::JpegIndex, .. } => EncodeError::BadOption {
            option: EncodeOption::Quality,
            value: options.quality.to_string(),
            reason: "too high for this material: eight MCUs after an indexed one take more \
                     than the index's 65535 bits; use a lower quality",
        },
        e => EncodeError::Format(e),
    })
}

/// Map `p` of mip `mip` as a JPEG file, indexed.
fn encode_image(
    set: &TextureSet,
    mip: usize,
    p: &PlannedMap,
    quality: u8,
    optimize: bool,
) -> Result<IndexedJpeg, EncodeError> {
    let image = &set.mips[mip];
    let (first, n) = (usize::from(p.map.first_channel), usize::from(p.map.channel_count));
    let failed = |detail: String| EncodeError::Jpeg {
        channel: set.channels[first].name.clone(),
        mip: mip as u32,
        detail,
    };
    let samples: Vec<u8> = image
        .data
        .chunks_exact(set.channel_count())
        .flat_map(|texel| &texel[first..first + n])
        .map(|&u| (u.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let side = |v: u32| u16::try_from(v).map_err(|_| failed(format!("{v} texels is too wide")));
    let (width, height) = (side(image.width)?, side(image.height)?);
    let mut file = Vec::new();
    let mut encoder = Encoder::new(&mut file, quality);
    encoder.set_optimized_huffman_tables(optimize);
    let colour_type = if n == 3 {
        let sampling = SamplingFactor::from_factors(p.map.luma_h, p.map.luma_v)
            .ok_or_else(|| failed("no such subsampling".into()))?;
        encoder.set_sampling_factor(sampling);
        if !p.colour {
            let luma = || QuantizationTableType::Custom(Box::new(luma_table(quality)));
            encoder.set_quantization_tables(luma(), luma());
        }
        ColorType::Rgb
    } else {
        ColorType::Luma
    };
    encoder.encode(&samples, width, height, colour_type).map_err(|e| failed(e.to_string()))?;
    let indexed = index_jpeg(&file).map_err(|e| failed(e.to_string()))?;
    if (indexed.map.channel_count, indexed.map.luma_h, indexed.map.luma_v)
        != (p.map.channel_count, p.map.luma_h, p.map.luma_v)
    {
        return Err(failed(format!("the encoder wrote a {:?} map", indexed.map)));
    }
    Ok(indexed)
}

/// The luma table of ITU T.81 Annex K (natural order) at `quality`, as the IJG library scales
/// it.
fn luma_table(quality: u8) -> [u16; 64] {
    const ANNEX_K_LUMA: [u16; 64] = [
        16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69,
        56, 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81,
        104, 113, 92, 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99,
    ];
    let q = u32::from(quality.clamp(1, 100));
    let scale = if q < 50 { 5000 / q } else { 200 - 2 * q };
    ANNEX_K_LUMA.map(|v| ((u32::from(v) * scale + 50) / 100).clamp(1, 255) as u16)
}
