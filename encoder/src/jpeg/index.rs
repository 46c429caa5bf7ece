//! Baseline JPEG files into indexed streams (docs/FORMAT.md §11) without re-encoding: the
//! markers are read, the entropy-coded data is walked once to find where every MCU starts and
//! what its DC values are, and byte stuffing and restart markers are dropped. The coefficients
//! are not touched, so the indexed stream decodes to exactly what the file holds.

use std::fmt;

use nmat_core::internals::{HuffmanProblem, QUANT_TABLE_LEN, check_huffman_table};
use nmat_core::{HuffmanTableSpec, JpegMap, JpegStreamSpec};

/// Why a JPEG file cannot be indexed.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JpegError {
    /// The file does not start with a JPEG start-of-image marker.
    NotJpeg,
    /// The file ends inside a marker segment or before the end of the scan.
    Truncated { offset: usize },
    /// A marker segment whose content contradicts the standard.
    BadSegment { marker: u8, offset: usize, reason: &'static str },
    /// Progressive JPEG: its coefficients come in several scans.
    Progressive,
    /// Arithmetic-coded, lossless or hierarchical JPEG (start-of-frame marker `0xFFCn`).
    UnsupportedFrame { marker: u8 },
    /// Only 8-bit samples are supported.
    Precision { bits: u8 },
    /// Only 1 (gray) or 3 (YCbCr) components are supported.
    Components { count: u8 },
    /// A sampling factor outside 1 … 4, which ITU T.81 §B.2.2 does not allow (libjpeg:
    /// `JERR_BAD_SAMPLING`). `component` counts from 0 in frame-header order; `id` is its
    /// component identifier.
    BadSampling { component: usize, id: u8, h: u8, v: u8 },
    /// Colour files must have 1×1 chroma and 1 or 2 luma samples per chroma sample each way.
    Sampling { component: usize, h: u8, v: u8 },
    /// The three components are RGB, not YCbCr, by libjpeg's rules (see [`RgbRule`]); the
    /// material decodes YCbCr only.
    NotYCbCr { rule: RgbRule },
    /// 16-bit quantization tables are not baseline.
    WideQuantTable { id: u8 },
    /// A component or scan names a table the file does not define.
    MissingTable { kind: &'static str, id: u8 },
    /// The image data is not one interleaved scan of every component.
    Scans,
    /// Height 0 (defined by a later DNL marker), not supported.
    DefinedByDnl,
    /// The entropy-coded data is corrupt at this MCU.
    Corrupt { mcu: usize, reason: &'static str },
    /// A DC value outside the 12 bits an index stores.
    DcRange { mcu: usize, value: i32 },
}

/// Which of libjpeg's colour-space rules (libjpeg-turbo `jdapimin.c`,
/// `default_decompress_parms`) found a 3-component file to be RGB. The rules, in order: a JFIF
/// APP0 marker means YCbCr; else an Adobe APP14 marker's transform 0 means RGB (any other
/// transform YCbCr); else component IDs 'R', 'G', 'B' mean RGB (any others YCbCr).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RgbRule {
    /// An Adobe APP14 marker with transform 0, and no JFIF marker.
    AdobeTransform0,
    /// Neither a JFIF nor an Adobe marker, and the component IDs are 'R', 'G', 'B' (82, 71, 66).
    ComponentIdsRgb,
}

impl fmt::Display for RgbRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RgbRule::AdobeTransform0 => {
                write!(f, "its Adobe APP14 marker says transform 0 and it has no JFIF marker")
            }
            RgbRule::ComponentIdsRgb => {
                write!(f, "it has no JFIF or Adobe marker and its component IDs are 'R', 'G', 'B'")
            }
        }
    }
}

/// The colour space libjpeg assumes for a 3-component file (see [`RgbRule`]), so that an indexed
/// file decodes as `djpeg` decodes it: `Some` where that is RGB.
fn rgb_rule(saw_jfif: bool, adobe_transform: Option<u8>, ids: [u8; 3]) -> Option<RgbRule> {
    if saw_jfif {
        return None;
    }
    match adobe_transform {
        Some(0) => Some(RgbRule::AdobeTransform0),
        // Transforms other than 0 and 1 are undefined; libjpeg warns and assumes YCbCr.
        Some(_) => None,
        None if ids == *b"RGB" => Some(RgbRule::ComponentIdsRgb),
        None => None,
    }
}

impl fmt::Display for JpegError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            JpegError::NotJpeg => write!(f, "not a JPEG file (no start-of-image marker FF D8)"),
            JpegError::Truncated { offset } => {
                write!(f, "the JPEG file ends early (at byte {offset})")
            }
            JpegError::BadSegment { marker, offset, reason } => {
                write!(f, "JPEG marker FF {marker:02X} at byte {offset}: {reason}")
            }
            JpegError::Progressive => write!(
                f,
                "progressive JPEG: only baseline files can be indexed; convert it without loss \
                 with `jpegtran -optimize IN.jpg > OUT.jpg` (libjpeg-turbo) and index that"
            ),
            JpegError::UnsupportedFrame { marker } => write!(
                f,
                "JPEG frame type FF {marker:02X} (arithmetic-coded, lossless or hierarchical) is \
                 not supported: only baseline Huffman-coded files can be indexed"
            ),
            JpegError::Precision { bits } => {
                write!(f, "{bits}-bit JPEG samples: only 8-bit files can be indexed")
            }
            JpegError::Components { count } => write!(
                f,
                "{count} colour components: only gray (1) or YCbCr (3) JPEG files can be indexed"
            ),
            JpegError::BadSampling { component, id, h, v } => write!(
                f,
                "component {component} (ID {id}) has sampling factors {h}×{v}: JPEG allows 1 to 4 \
                 each way"
            ),
            JpegError::Sampling { component, h, v } => write!(
                f,
                "component {component} has sampling factors {h}×{v}: supported are luma 1×1, 2×1, \
                 1×2 or 2×2 with chroma 1×1 (4:4:4, 4:2:2, 4:4:0, 4:2:0)"
            ),
            JpegError::NotYCbCr { rule } => write!(
                f,
                "the JPEG stores RGB, not YCbCr ({rule}; libjpeg decodes it as RGB), and only \
                 YCbCr or gray files can be indexed: convert it, e.g. `djpeg IN.jpg | cjpeg \
                 -quality 95 -outfile OUT.jpg` (libjpeg-turbo; lossy) or re-save it as an \
                 ordinary JPEG in an image editor, and index that"
            ),
            JpegError::WideQuantTable { id } => {
                write!(
                    f,
                    "quantization table {id} has 16-bit entries, which baseline JPEG does not allow"
                )
            }
            JpegError::MissingTable { kind, id } => {
                write!(f, "the JPEG uses {kind} table {id} but does not define it")
            }
            JpegError::Scans => {
                write!(f, "the JPEG's image data is not one interleaved scan of all its components")
            }
            JpegError::DefinedByDnl => {
                write!(f, "the JPEG defines its height later (DNL marker), which is not supported")
            }
            JpegError::Corrupt { mcu, reason } => {
                write!(f, "corrupt JPEG data in MCU {mcu}: {reason}")
            }
            JpegError::DcRange { mcu, value } => write!(
                f,
                "MCU {mcu} has DC value {value}, outside the 12-bit range [-2048, 2047] of an index"
            ),
        }
    }
}

impl std::error::Error for JpegError {}

/// A baseline JPEG file as one indexed stream, with the tables it uses (numbered from 0 in the
/// order of `quant` and `huffman`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IndexedJpeg {
    pub width: u32,
    pub height: u32,
    /// The map's layout (`first_channel` 0).
    pub map: JpegMap,
    pub quant: Vec<[u8; QUANT_TABLE_LEN]>,
    pub huffman: Vec<HuffmanTableSpec>,
    pub stream: JpegStreamSpec,
}

#[derive(Clone, Copy)]
struct Component {
    id: u8,
    h: u8,
    v: u8,
    tq: u8,
    td: u8,
    ta: u8,
}

/// A Huffman table ready to decode strictly (an unknown code is an error).
struct Decoding {
    maxcode: [i32; 17],
    offset: [i32; 17],
    values: Vec<u8>,
}

impl Decoding {
    fn new(t: &HuffmanTableSpec) -> Decoding {
        let (mut maxcode, mut offset) = ([-1i32; 17], [0i32; 17]);
        let (mut code, mut k) = (0i32, 0i32);
        for l in 1..=16 {
            let n = i32::from(t.counts[l - 1]);
            offset[l] = k - code;
            if n > 0 {
                maxcode[l] = code + n - 1;
            }
            code = (code + n) << 1;
            k += n;
        }
        Decoding { maxcode, offset, values: t.values.clone() }
    }
}

struct Reader<'a> {
    data: &'a [u8],
    pos: u64,
}

impl Reader<'_> {
    fn bit(&mut self) -> Option<u32> {
        let byte = *self.data.get(usize::try_from(self.pos / 8).ok()?)?;
        let b = (byte >> (7 - self.pos % 8)) & 1;
        self.pos += 1;
        Some(u32::from(b))
    }
    fn bits(&mut self, n: u32) -> Option<u32> {
        (0..n).try_fold(0u32, |v, _| Some((v << 1) | self.bit()?))
    }
    fn symbol(&mut self, t: &Decoding) -> Option<u8> {
        let mut code = 0i32;
        for l in 1..=16 {
            code = (code << 1) | self.bit()? as i32;
            if code <= t.maxcode[l] {
                return t.values.get((code + t.offset[l]) as usize).copied();
            }
        }
        None
    }
}

fn extend(v: u32, n: u32) -> i32 {
    if n == 0 {
        0
    } else if v < (1 << (n - 1)) {
        v as i32 - (1 << n) + 1
    } else {
        v as i32
    }
}

/// Indexes a baseline JPEG file.
pub fn index_jpeg(file: &[u8]) -> Result<IndexedJpeg, JpegError> {
    if file.get(..2) != Some(&[0xFF, 0xD8]) {
        return Err(JpegError::NotJpeg);
    }
    let mut quant: [Option<[u8; 64]>; 4] = [None; 4];
    let mut dc_tables: [Option<HuffmanTableSpec>; 4] = Default::default();
    let mut ac_tables: [Option<HuffmanTableSpec>; 4] = Default::default();
    let mut frame: Option<(u32, u32, Vec<Component>)> = None;
    let mut restart = 0usize;
    // What libjpeg reads of the APP0 and APP14 markers to decide the colour space (`rgb_rule`).
    let mut saw_jfif = false;
    let mut adobe_transform = None;
    let mut pos = 2;
    loop {
        // Fill bytes (FF) may precede a marker.
        while file.get(pos) == Some(&0xFF) && file.get(pos + 1) == Some(&0xFF) {
            pos += 1;
        }
        let (Some(&0xFF), Some(&marker)) = (file.get(pos), file.get(pos + 1)) else {
            return Err(JpegError::Truncated { offset: pos });
        };
        let at = pos;
        pos += 2;
        if marker == 0xD9 {
            return Err(JpegError::Scans);
        }
        if (0xD0..=0xD7).contains(&marker) || marker == 0x01 {
            continue;
        }
        let len = usize::from(u16::from_be_bytes([
            *file.get(pos).ok_or(JpegError::Truncated { offset: pos })?,
            *file.get(pos + 1).ok_or(JpegError::Truncated { offset: pos })?,
        ]));
        let seg = file
            .get(pos + 2..pos + len)
            .filter(|_| len >= 2)
            .ok_or(JpegError::Truncated { offset: pos })?;
        let bad = |reason| JpegError::BadSegment { marker, offset: at, reason };
        match marker {
            0xDB => {
                let mut s = seg;
                while let Some((&pq_tq, rest)) = s.split_first() {
                    let (pq, tq) = (pq_tq >> 4, pq_tq & 15);
                    if pq != 0 {
                        return Err(JpegError::WideQuantTable { id: tq });
                    }
                    let table = rest.get(..64).ok_or(bad("quantization table cut short"))?;
                    if tq > 3 || table.contains(&0) {
                        return Err(bad("bad quantization table id or a zero entry"));
                    }
                    quant[usize::from(tq)] =
                        Some(table.try_into().map_err(|_| bad("short table"))?);
                    s = &rest[64..];
                }
            }
            0xC4 => {
                let mut s = seg;
                while let Some((&tc_th, rest)) = s.split_first() {
                    let (tc, th) = (tc_th >> 4, tc_th & 15);
                    let counts: [u8; 16] = rest
                        .get(..16)
                        .ok_or(bad("Huffman table cut short"))?
                        .try_into()
                        .map_err(|_| bad("short"))?;
                    let n: usize = counts.iter().map(|&c| usize::from(c)).sum();
                    let values =
                        rest.get(16..16 + n).ok_or(bad("Huffman table cut short"))?.to_vec();
                    if tc > 1 || th > 3 {
                        return Err(bad("bad Huffman table class or id"));
                    }
                    check_huffman_table(tc, &counts, &values).map_err(|p| {
                        bad(match p {
                            HuffmanProblem::Count(_) => "a Huffman table without codes",
                            HuffmanProblem::Length(_) => {
                                "a Huffman table whose codes overflow their lengths"
                            }
                            HuffmanProblem::Symbol(_) => {
                                "a Huffman table with a symbol baseline JPEG does not have"
                            }
                        })
                    })?;
                    let t = Some(HuffmanTableSpec { class: tc, counts, values });
                    if tc == 0 {
                        dc_tables[usize::from(th)] = t
                    } else {
                        ac_tables[usize::from(th)] = t
                    }
                    s = &rest[16 + n..];
                }
            }
            0xC0 | 0xC1 => {
                let [p, h1, h0, w1, w0, nf, ..] = *seg else {
                    return Err(bad("frame header cut short"));
                };
                if p != 8 {
                    return Err(JpegError::Precision { bits: p });
                }
                let (w, h) = (
                    u32::from(u16::from_be_bytes([w1, w0])),
                    u32::from(u16::from_be_bytes([h1, h0])),
                );
                if h == 0 {
                    return Err(JpegError::DefinedByDnl);
                }
                if w == 0 {
                    return Err(bad("width 0"));
                }
                if nf != 1 && nf != 3 {
                    return Err(JpegError::Components { count: nf });
                }
                let mut comps = Vec::new();
                for c in 0..usize::from(nf) {
                    let r = seg.get(6 + 3 * c..9 + 3 * c).ok_or(bad("frame header cut short"))?;
                    let (id, h, v) = (r[0], r[1] >> 4, r[1] & 15);
                    // Checked for gray files too, as libjpeg does, although their factors are
                    // otherwise ignored (one component: an MCU is one block).
                    if !(1..=4).contains(&h) || !(1..=4).contains(&v) {
                        return Err(JpegError::BadSampling { component: c, id, h, v });
                    }
                    comps.push(Component { id, h, v, tq: r[2], td: 0, ta: 0 });
                }
                frame = Some((w, h, comps));
            }
            0xC2 | 0xC6 | 0xCA | 0xCE => return Err(JpegError::Progressive),
            0xC3 | 0xC5 | 0xC7 | 0xC9 | 0xCB | 0xCD | 0xCF => {
                return Err(JpegError::UnsupportedFrame { marker });
            }
            0xDD => {
                let [r1, r0, ..] = *seg else { return Err(bad("restart interval cut short")) };
                restart = usize::from(u16::from_be_bytes([r1, r0]));
            }
            // libjpeg's lengths (jdmarker.c): 14 bytes of JFIF data, 12 of Adobe data; a shorter
            // segment is not that marker. A later Adobe marker replaces an earlier one's transform.
            0xE0 if seg.len() >= 14 && seg.starts_with(b"JFIF\0") => saw_jfif = true,
            0xEE if seg.starts_with(b"Adobe") => {
                if let Some(&transform) = seg.get(11) {
                    adobe_transform = Some(transform);
                }
            }
            0xDC => return Err(JpegError::DefinedByDnl),
            0xDA => {
                let (w, h, mut comps) = frame.ok_or(bad("scan before the frame header"))?;
                let ns = usize::from(*seg.first().ok_or(bad("scan header cut short"))?);
                if ns != comps.len() {
                    return Err(JpegError::Scans);
                }
                for k in 0..ns {
                    let r = seg.get(1 + 2 * k..3 + 2 * k).ok_or(bad("scan header cut short"))?;
                    let c = comps
                        .iter_mut()
                        .find(|c| c.id == r[0])
                        .ok_or(bad("scan names an unknown component"))?;
                    (c.td, c.ta) = (r[1] >> 4, r[1] & 15);
                }
                if seg.get(1 + 2 * ns..4 + 2 * ns) != Some(&[0, 63, 0]) {
                    return Err(bad("spectral selection or approximation of a non-baseline scan"));
                }
                if let [a, b, c] = comps[..]
                    && let Some(rule) = rgb_rule(saw_jfif, adobe_transform, [a.id, b.id, c.id])
                {
                    return Err(JpegError::NotYCbCr { rule });
                }
                return index_scan(
                    file,
                    pos + len,
                    (w, h),
                    &comps,
                    restart,
                    &quant,
                    &dc_tables,
                    &ac_tables,
                );
            }
            _ => {}
        }
        pos += len;
    }
}

#[allow(clippy::too_many_arguments)]
fn index_scan(
    file: &[u8],
    start: usize,
    (width, height): (u32, u32),
    comps: &[Component],
    restart: usize,
    quant: &[Option<[u8; 64]>; 4],
    dc_tables: &[Option<HuffmanTableSpec>; 4],
    ac_tables: &[Option<HuffmanTableSpec>; 4],
) -> Result<IndexedJpeg, JpegError> {
    let colour = comps.len() == 3;
    // A gray file's one scan is non-interleaved, where an MCU is one block whatever the (valid)
    // factors say (T.81 §A.2.2); libjpeg decodes it so too.
    let (lh, lv) = if colour { (comps[0].h, comps[0].v) } else { (1, 1) };
    if colour {
        if !(1..=2).contains(&lh) || !(1..=2).contains(&lv) {
            return Err(JpegError::Sampling { component: 0, h: lh, v: lv });
        }
        for (k, c) in comps.iter().enumerate().skip(1) {
            if (c.h, c.v) != (1, 1) {
                return Err(JpegError::Sampling { component: k, h: c.h, v: c.v });
            }
        }
    }
    // Tables, numbered in the order the components first use them.
    let mut out_quant: Vec<[u8; 64]> = Vec::new();
    let mut out_huffman: Vec<HuffmanTableSpec> = Vec::new();
    let (mut q_ref, mut dc_ref, mut ac_ref) = ([0u8; 3], [0u8; 3], [0u8; 3]);
    let mut decoders = Vec::new();
    for (k, c) in comps.iter().enumerate() {
        let q = quant
            .get(usize::from(c.tq))
            .cloned()
            .flatten()
            .ok_or(JpegError::MissingTable { kind: "quantization", id: c.tq })?;
        q_ref[k] = position_or_push(&mut out_quant, q);
        let dc = dc_tables
            .get(usize::from(c.td))
            .cloned()
            .flatten()
            .ok_or(JpegError::MissingTable { kind: "DC Huffman", id: c.td })?;
        let ac = ac_tables
            .get(usize::from(c.ta))
            .cloned()
            .flatten()
            .ok_or(JpegError::MissingTable { kind: "AC Huffman", id: c.ta })?;
        decoders.push((Decoding::new(&dc), Decoding::new(&ac)));
        dc_ref[k] = position_or_push(&mut out_huffman, dc);
        ac_ref[k] = position_or_push(&mut out_huffman, ac);
    }
    // The entropy-coded data without stuffing and markers; where each restart interval starts.
    let mut data = Vec::new();
    let mut restarts = Vec::new();
    let mut p = start;
    loop {
        let &b = file.get(p).ok_or(JpegError::Truncated { offset: p })?;
        if b != 0xFF {
            data.push(b);
            p += 1;
            continue;
        }
        let &m = file.get(p + 1).ok_or(JpegError::Truncated { offset: p })?;
        match m {
            0x00 => {
                data.push(0xFF);
                p += 2;
            }
            0xD0..=0xD7 => {
                restarts.push(data.len());
                p += 2;
            }
            0xFF => p += 1,
            _ => break,
        }
    }
    let (mw, mh) = (8 * u32::from(lh), 8 * u32::from(lv));
    let mcus = (width.div_ceil(mw) * height.div_ceil(mh)) as usize;
    let mut reader = Reader { data: &data, pos: 0 };
    let mut pred = [0i32; 3];
    // Every MCU takes at least one bit per block: a header declaring more MCUs than the data can
    // hold fails in the walk below, before it is reserved for.
    let room = mcus.min(8 * data.len() + 1);
    let mut mcu_bits = Vec::with_capacity(room);
    let mut dcs = Vec::with_capacity(room * comps.len());
    let mut next_restart = restarts.iter();
    for mcu in 0..mcus {
        if restart > 0 && mcu > 0 && mcu % restart == 0 {
            let &at = next_restart
                .next()
                .ok_or(JpegError::Corrupt { mcu, reason: "a restart marker is missing" })?;
            if reader.pos > 8 * at as u64 {
                let reason = "the MCUs before a restart marker run past it";
                return Err(JpegError::Corrupt { mcu: mcu - 1, reason });
            }
            reader.pos = 8 * at as u64;
            pred = [0; 3];
        }
        mcu_bits.push(reader.pos);
        for (k, (dc_t, ac_t)) in decoders.iter().enumerate() {
            let blocks = if k == 0 && colour { usize::from(lh) * usize::from(lv) } else { 1 };
            for b in 0..blocks {
                let corrupt = |reason| JpegError::Corrupt { mcu, reason };
                let s = reader.symbol(dc_t).ok_or(corrupt("bad DC code or data ends"))?;
                if s > 11 {
                    return Err(corrupt("DC difference of more than 11 bits"));
                }
                let v = reader.bits(u32::from(s)).ok_or(corrupt("data ends"))?;
                pred[k] += extend(v, u32::from(s));
                if b == 0 {
                    let dc = pred[k];
                    dcs.push(
                        i16::try_from(dc)
                            .ok()
                            .filter(|d| (-2048..=2047).contains(d))
                            .ok_or(JpegError::DcRange { mcu, value: dc })?,
                    );
                }
                let mut i = 1;
                while i < 64 {
                    let rs = reader.symbol(ac_t).ok_or(corrupt("bad AC code or data ends"))?;
                    let (run, size) = (usize::from(rs >> 4), u32::from(rs & 15));
                    if size == 0 {
                        if run != 15 {
                            break;
                        }
                        i += 16;
                        continue;
                    }
                    i += run;
                    if i > 63 || size > 10 {
                        return Err(corrupt("coefficients past the end of a block"));
                    }
                    reader.bits(size).ok_or(corrupt("data ends"))?;
                    i += 1;
                }
                if i > 64 {
                    return Err(corrupt("coefficients past the end of a block"));
                }
            }
        }
    }
    let map =
        JpegMap { first_channel: 0, channel_count: comps.len() as u8, luma_h: lh, luma_v: lv };
    let stream = JpegStreamSpec { quant: q_ref, dc: dc_ref, ac: ac_ref, mcu_bits, dcs, data };
    Ok(IndexedJpeg { width, height, map, quant: out_quant, huffman: out_huffman, stream })
}

pub(super) fn position_or_push<T: PartialEq>(list: &mut Vec<T>, item: T) -> u8 {
    match list.iter().position(|x| *x == item) {
        Some(i) => i as u8,
        None => {
            list.push(item);
            (list.len() - 1) as u8
        }
    }
}

/// A one-map, one-mip JPEG material from an indexed file — what `nmat index` writes: channels
/// R, G, B (albedo, sRGB) for a colour file, one gray channel (albedo, sRGB) for a gray one, and
/// a SOURCE_MAPS section naming the map `decoded_name` (e.g. `photo.png`), under which `nmat
/// decode` writes it back as one RGB or gray image.
pub fn material_from_jpeg(
    indexed: &IndexedJpeg,
    decoded_name: &str,
) -> nmat_core::JpegMaterialSpec {
    use crate::texset::{FileLayout, Role, SourceMap};
    use nmat_core::{AddressMode, ChannelSpec, ColorSpace, Semantic};
    let channel = |name: &str, component, semantic, color_space| ChannelSpec {
        name: name.to_string(),
        semantic,
        component,
        color_space,
        range_min: 0.0,
        range_max: 1.0,
    };
    let channels = if indexed.map.channel_count == 3 {
        ["R", "G", "B"]
            .iter()
            .enumerate()
            .map(|(k, n)| channel(n, k as u8, Semantic::ALBEDO, ColorSpace::Srgb))
            .collect()
    } else {
        vec![channel("gray", 0, Semantic::ALBEDO, ColorSpace::Srgb)]
    };
    let colour = indexed.map.channel_count == 3;
    let map = SourceMap {
        role: Role::Albedo,
        file_name: decoded_name.to_string(),
        layout: if colour { FileLayout::Rgb } else { FileLayout::Gray },
        first_channel: 0,
        channel_count: usize::from(indexed.map.channel_count),
        gray_rgb: false,
        alpha_value: None,
        sixteen_bit: false,
    };
    nmat_core::JpegMaterialSpec {
        width: indexed.width,
        height: indexed.height,
        mip_count: 1,
        address_mode: AddressMode::Wrap,
        channels,
        maps: vec![indexed.map],
        quant_tables: indexed.quant.clone(),
        huffman_tables: indexed.huffman.clone(),
        streams: vec![indexed.stream.clone()],
        optional_sections: vec![(
            crate::source_maps::SECTION_KIND,
            crate::source_maps::encode(std::slice::from_ref(&map)),
        )],
    }
}
