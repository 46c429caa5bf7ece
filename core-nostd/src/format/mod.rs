//! The container format: the file's identity and versions, its section table and checksum, and
//! what every material has whatever its codec (channels, addressing, mip sizes); parsing builds a
//! `Material` from it (FORMAT.md §1–§3).

pub(crate) mod channel;
pub(crate) mod checksum;
pub(crate) mod container;
pub(crate) mod packed;
pub(crate) mod version;
