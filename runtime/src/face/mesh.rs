//! The face mesh (ICT-FaceKit's face region, MIT licence; `runtime/assets/face/`, built by
//! `python -m livegesture.face.mesh`): neutral positions, triangles and one sparse morph target per
//! ARKit name (float16 deltas in metres), read from the asset compiled into the binary.

use anyhow::{ensure, Result};

use super::{ARKIT_DIM, ARKIT_NAMES};

static ASSET: &[u8] = include_bytes!("../../assets/face/ict_face.bin");
const MAGIC: &[u8; 8] = b"LGFACE01";

/// The face mesh (see the module docs).
#[derive(Debug, Clone)]
pub struct FaceMesh {
    /// `(n, 3)` neutral positions, metres, y up, facing +z, centred on the face.
    pub positions: Vec<f32>,
    /// Triangles (counter-clockwise), vertex indices.
    pub triangles: Vec<u16>,
    /// Per ARKit name ([`ARKIT_NAMES`] order): the moving vertices and their `(x, y, z)` deltas.
    pub targets: Vec<(Vec<u16>, Vec<f32>)>,
}

impl FaceMesh {
    /// Vertex count.
    pub fn n_vertices(&self) -> usize {
        self.positions.len() / 3
    }
}

/// IEEE 754 half -> single precision.
fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h >> 15) as u32) << 31;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    let bits = match (exp, man) {
        (0, 0) => sign,
        (0, m) => {
            // subnormal: normalise
            let mut e: i32 = -14;
            let mut m = m;
            while m & 0x400 == 0 {
                m <<= 1;
                e -= 1;
            }
            sign | (((e + 127) as u32) << 23) | ((m & 0x3ff) << 13)
        }
        (0x1f, m) => sign | 0x7f80_0000 | (m << 13),
        (e, m) => sign | ((e + 112) << 23) | (m << 13),
    };
    f32::from_bits(bits)
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        ensure!(
            self.at + n <= self.b.len(),
            "face mesh asset: truncated at byte {} (needs {n} more)",
            self.at
        );
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
}

/// The compiled-in asset's bytes (`LGFACE01`; the layout [`face_mesh`] reads): what `serve` sends
/// the page at `/face.bin`.
pub fn asset_bytes() -> &'static [u8] {
    ASSET
}

/// Parses the compiled-in asset.
pub fn face_mesh() -> Result<FaceMesh> {
    parse(ASSET)
}

fn parse(b: &[u8]) -> Result<FaceMesh> {
    let mut r = Reader { b, at: 0 };
    ensure!(r.take(8)? == MAGIC, "face mesh asset: bad magic");
    let n = r.u32()? as usize;
    let t = r.u32()? as usize;
    let k = r.u32()? as usize;
    ensure!(
        k == ARKIT_DIM && n <= u16::MAX as usize + 1,
        "face mesh asset: {k} targets for {n} vertices, expected {ARKIT_DIM} and at most 65536"
    );
    let positions = r
        .take(12 * n)?
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    let triangles: Vec<u16> = r
        .take(6 * t)?
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    ensure!(
        triangles.iter().all(|&i| (i as usize) < n),
        "face mesh asset: a triangle index is out of range"
    );
    let mut targets = Vec::with_capacity(k);
    for name in ARKIT_NAMES {
        let c = r.u32()? as usize;
        let idx: Vec<u16> = r
            .take(2 * c)?
            .chunks_exact(2)
            .map(|x| u16::from_le_bytes([x[0], x[1]]))
            .collect();
        ensure!(
            idx.windows(2).all(|w| w[0] < w[1]) && idx.iter().all(|&i| (i as usize) < n),
            "face mesh asset: target {name}: indices not increasing or out of range"
        );
        let d = r
            .take(6 * c)?
            .chunks_exact(2)
            .map(|x| f16_to_f32(u16::from_le_bytes([x[0], x[1]])))
            .collect();
        targets.push((idx, d));
    }
    ensure!(
        r.at == b.len(),
        "face mesh asset: {} trailing bytes",
        b.len() - r.at
    );
    Ok(FaceMesh {
        positions,
        triangles,
        targets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_asset_parses_and_its_targets_move_the_face() {
        let m = face_mesh().unwrap();
        assert_eq!(m.n_vertices(), 9409);
        assert_eq!(m.targets.len(), 52);
        let jaw = &m.targets[17];
        assert!(jaw.0.len() > 1000, "jawOpen moves {} vertices", jaw.0.len());
        let max = jaw.1.iter().fold(0f32, |a, x| a.max(x.abs()));
        assert!(max > 0.01 && max < 0.1, "jawOpen moves up to {max} m");
        assert!(m.targets[51].0.is_empty(), "tongueOut has no ICT shape");
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        // a truncated asset is refused, naming where
        let e = parse(&ASSET[..ASSET.len() - 3]).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }
}
