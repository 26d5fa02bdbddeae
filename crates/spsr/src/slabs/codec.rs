//! The files that the phases of a slab run exchange when they run as separate tasks
//! ([`super::job`]): each kind of data as a little-endian binary record behind an 8-byte tag,
//! written atomically (a task that dies leaves no half file) and read back exactly (every
//! float keeps its bits, so a run of tasks gives the same mesh as a run in one process).

use std::io::Write;
use std::path::{Path, PathBuf};

use super::phases::{CoarsePart, SlabSamples, Solved};
use crate::data::KeyedSums;
use crate::density::{DepthAndArea, Sample};
use crate::extract::Part;
use crate::pipeline::noise;
use crate::solver::{Carry, CycleState};
use crate::system::ClusterSum;
use crate::{Error, Result};

/// Writes little-endian values.
pub(crate) struct Out<'a>(&'a mut dyn Write);

impl Out<'_> {
    pub fn u32(&mut self, v: u32) -> std::io::Result<()> {
        self.0.write_all(&v.to_le_bytes())
    }
    pub fn u64(&mut self, v: u64) -> std::io::Result<()> {
        self.0.write_all(&v.to_le_bytes())
    }
    pub fn f32(&mut self, v: f32) -> std::io::Result<()> {
        self.0.write_all(&v.to_le_bytes())
    }
    pub fn f64(&mut self, v: f64) -> std::io::Result<()> {
        self.0.write_all(&v.to_le_bytes())
    }
    pub fn len(&mut self, n: usize) -> std::io::Result<()> {
        self.u64(n as u64)
    }
    pub fn key(&mut self, k: [u32; 3]) -> std::io::Result<()> {
        k.iter().try_for_each(|&c| self.u32(c))
    }
    /// A list: its length, then `item` for each element.
    pub fn list<T>(
        &mut self,
        xs: &[T],
        mut item: impl FnMut(&mut Self, &T) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        self.len(xs.len())?;
        xs.iter().try_for_each(|x| item(self, x))
    }
}

/// Reads what [`Out`] wrote, from a file read whole; a short or malformed file is an error
/// naming it.
pub(crate) struct In {
    bytes: Vec<u8>,
    at: usize,
    path: PathBuf,
}

impl In {
    fn take<const N: usize>(&mut self) -> Result<[u8; N]> {
        let end = self.at + N;
        let b = self
            .bytes
            .get(self.at..end)
            .ok_or_else(|| self.bad("ends early"))?;
        self.at = end;
        Ok(b.try_into().expect("N bytes"))
    }
    fn bad(&self, what: &str) -> Error {
        Error::Parse {
            path: self.path.clone(),
            message: format!(
                "this slab task's file {what} (written by another version, or damaged)"
            ),
        }
    }
    pub fn u32(&mut self) -> Result<u32> {
        self.take().map(u32::from_le_bytes)
    }
    pub fn u64(&mut self) -> Result<u64> {
        self.take().map(u64::from_le_bytes)
    }
    pub fn f32(&mut self) -> Result<f32> {
        self.take().map(f32::from_le_bytes)
    }
    pub fn f64(&mut self) -> Result<f64> {
        self.take().map(f64::from_le_bytes)
    }
    /// A length, checked against the bytes left (each element at least `min_size` bytes).
    pub fn len(&mut self, min_size: usize) -> Result<usize> {
        let n = self.u64()?;
        let left = (self.bytes.len() - self.at) as u64;
        if n.saturating_mul(min_size.max(1) as u64) > left {
            return Err(self.bad("holds a length longer than the file"));
        }
        Ok(n as usize)
    }
    pub fn key(&mut self) -> Result<[u32; 3]> {
        Ok([self.u32()?, self.u32()?, self.u32()?])
    }
    pub fn list<T>(
        &mut self,
        min_size: usize,
        mut item: impl FnMut(&mut Self) -> Result<T>,
    ) -> Result<Vec<T>> {
        let n = self.len(min_size)?;
        (0..n).map(|_| item(self)).collect()
    }
}

/// A kind of data a task writes for others.
pub(crate) trait Record: Sized {
    /// The file's first eight bytes.
    const TAG: &'static [u8; 8];
    fn put(&self, o: &mut Out) -> std::io::Result<()>;
    fn get(i: &mut In) -> Result<Self>;
}

/// Writes `r` to `path` atomically.
pub(crate) fn save<R: Record>(path: &Path, r: &R) -> Result<()> {
    crate::io::write_with(path, |w| {
        w.write_all(R::TAG)?;
        r.put(&mut Out(w))
    })
}

/// Reads a record that [`save`] wrote.
pub(crate) fn load<R: Record>(path: &Path) -> Result<R> {
    let bytes = std::fs::read(path).map_err(|e| super::spill::io_err(path, e))?;
    let mut i = In {
        bytes,
        at: 0,
        path: path.to_path_buf(),
    };
    if i.take::<8>()? != *R::TAG {
        return Err(i.bad("is not of the kind expected"));
    }
    let r = R::get(&mut i)?;
    if i.at != i.bytes.len() {
        return Err(i.bad("has bytes after its end"));
    }
    Ok(r)
}

fn put_levels_u64(o: &mut Out, levels: &[Vec<u64>]) -> std::io::Result<()> {
    o.list(levels, |o, l| o.list(l, |o, &k| o.u64(k)))
}

fn get_levels_u64(i: &mut In) -> Result<Vec<Vec<u64>>> {
    i.list(8, |i| i.list(8, In::u64))
}

pub(crate) fn put_levels_f32(o: &mut Out, levels: &[Vec<f32>]) -> std::io::Result<()> {
    o.list(levels, |o, l| o.list(l, |o, &x| o.f32(x)))
}

pub(crate) fn get_levels_f32(i: &mut In) -> Result<Vec<Vec<f32>>> {
    i.list(8, |i| i.list(4, In::f32))
}

fn put3_f32(o: &mut Out, v: [f32; 3]) -> std::io::Result<()> {
    v.iter().try_for_each(|&c| o.f32(c))
}

fn get3_f32(i: &mut In) -> Result<[f32; 3]> {
    Ok([i.f32()?, i.f32()?, i.f32()?])
}

fn put3_f64(o: &mut Out, v: [f64; 3]) -> std::io::Result<()> {
    v.iter().try_for_each(|&c| o.f64(c))
}

fn get3_f64(i: &mut In) -> Result<[f64; 3]> {
    Ok([i.f64()?, i.f64()?, i.f64()?])
}

impl Record for CoarsePart {
    const TAG: &'static [u8; 8] = b"spsrCPT3";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        put_levels_u64(o, &self.refined)?;
        o.list(&self.nodes, |o, l| {
            o.list(l, |o, &(k, b, v)| {
                o.key(k)?;
                o.f32(b)?;
                put3_f32(o, v)
            })
        })?;
        o.list(&self.clusters, |o, l| {
            o.list(l, |o, &(k, w, wp)| {
                o.key(k)?;
                o.f64(w)?;
                put3_f64(o, wp)
            })
        })?;
        put3_f64(o, self.sums)?;
        o.len(self.samples)?;
        o.list(&self.density, |o, &(c, w, wp)| {
            c.iter().try_for_each(|&x| o.u64(x as u64))?;
            o.f64(w)?;
            put3_f64(o, wp)
        })?;
        put_keyed_sums(o, &self.data)
    }
    fn get(i: &mut In) -> Result<Self> {
        Ok(CoarsePart {
            refined: get_levels_u64(i)?,
            nodes: i.list(8, |i| {
                i.list(28, |i| Ok((i.key()?, i.f32()?, get3_f32(i)?)))
            })?,
            clusters: i.list(8, |i| {
                i.list(44, |i| Ok((i.key()?, i.f64()?, get3_f64(i)?)))
            })?,
            sums: get3_f64(i)?,
            samples: i.u64()? as usize,
            density: i.list(56, |i| {
                let c = [i.u64()? as i64, i.u64()? as i64, i.u64()? as i64];
                Ok((c, i.f64()?, get3_f64(i)?))
            })?,
            data: get_keyed_sums(i)?,
        })
    }
}

/// Attribute sums per tree depth, keyed by node (`phases::CoarsePart::data`).
fn put_keyed_sums(o: &mut Out, levels: &[KeyedSums]) -> std::io::Result<()> {
    o.list(levels, |o, l| {
        o.list(&l.keys, |o, &k| o.key(k))?;
        o.list(&l.sums, |o, &x| o.f64(x))
    })
}

fn get_keyed_sums(i: &mut In) -> Result<Vec<KeyedSums>> {
    i.list(16, |i| {
        let keys = i.list(12, In::key)?;
        let sums = i.list(8, In::f64)?;
        if (keys.is_empty() && !sums.is_empty())
            || (!keys.is_empty() && sums.len() % keys.len() != 0)
        {
            return Err(i.bad("does not give every node its sums"));
        }
        Ok(KeyedSums { keys, sums })
    })
}

/// The whole cloud's attribute sums at the coarse depths (`phases::save_coarse_data`).
pub(crate) struct CoarseData(pub Vec<KeyedSums>);

impl Record for CoarseData {
    const TAG: &'static [u8; 8] = b"spsrDAT1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        put_keyed_sums(o, &self.0)
    }
    fn get(i: &mut In) -> Result<Self> {
        get_keyed_sums(i).map(CoarseData)
    }
}

impl Record for Solved {
    const TAG: &'static [u8; 8] = b"spsrSLV1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.f64(self.iso_sums[0])?;
        o.f64(self.iso_sums[1])?;
        for band in &self.faces {
            o.list(band, |o, &(t, k, x)| {
                o.u32(t)?;
                o.key(k)?;
                o.f32(x)
            })?;
        }
        Ok(())
    }
    fn get(i: &mut In) -> Result<Self> {
        let iso_sums = [i.f64()?, i.f64()?];
        let band = |i: &mut In| i.list(20, |i| Ok((i.u32()?, i.key()?, i.f32()?)));
        let faces = [band(i)?, band(i)?];
        Ok(Solved { iso_sums, faces })
    }
}

impl Record for Part {
    const TAG: &'static [u8; 8] = b"spsrPRT3";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.list(&self.vertices, |o, &v| put3_f64(o, v))?;
        match &self.normals {
            None => o.u32(0)?,
            Some(n) => {
                o.u32(1)?;
                o.list(n, |o, &v| put3_f32(o, v))?;
            }
        }
        o.list(&self.keys, |o, &k| o.u64(k))?;
        o.list(&self.triangles, |o, t| t.iter().try_for_each(|&c| o.u64(c)))?;
        match &self.density {
            None => o.u32(0)?,
            Some(d) => {
                o.u32(1)?;
                o.list(d, |o, &x| o.f32(x))?;
            }
        }
        o.list(self.attributes.as_deref().unwrap_or(&[]), |o, &x| o.f64(x))
    }
    fn get(i: &mut In) -> Result<Self> {
        let vertices = i.list(24, get3_f64)?;
        let normals = match i.u32()? {
            0 => None,
            _ => Some(i.list(12, get3_f32)?),
        };
        let keys = i.list(8, In::u64)?;
        let triangles = i.list(24, |i| Ok([i.u64()?, i.u64()?, i.u64()?]))?;
        let density = match i.u32()? {
            0 => None,
            _ => Some(i.list(4, In::f32)?),
        };
        let attributes = i.list(8, In::f64)?;
        let n = vertices.len();
        // The attributes' count is the job's (checked where the parts are put together).
        if normals.as_ref().is_some_and(|x| x.len() != n)
            || keys.len() != n
            || density.as_ref().is_some_and(|x| x.len() != n)
            || (n == 0 && !attributes.is_empty())
            || (n > 0 && attributes.len() % n != 0)
        {
            return Err(i.bad("does not give every vertex its values"));
        }
        Ok(Part {
            vertices,
            normals,
            keys,
            triangles,
            density,
            attributes: (!attributes.is_empty()).then_some(attributes),
        })
    }
}

/// The whole cloud's density estimator at its coarse depths (`phases::coarse_density`).
pub(crate) struct CoarseDensity(pub Vec<rustc_hash::FxHashMap<u64, f64>>);

impl Record for CoarseDensity {
    const TAG: &'static [u8; 8] = b"spsrDEN1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.list(&self.0, |o, map| {
            // In key order, so that the file's bytes do not depend on the hash map.
            let mut entries: Vec<(u64, f64)> = map.iter().map(|(&k, &v)| (k, v)).collect();
            entries.sort_unstable_by_key(|e| e.0);
            o.list(&entries, |o, &(k, v)| {
                o.u64(k)?;
                o.f64(v)
            })
        })
    }
    fn get(i: &mut In) -> Result<Self> {
        let levels = i.list(8, |i| {
            let entries = i.list(16, |i| Ok((i.u64()?, i.f64()?)))?;
            Ok(entries.into_iter().collect())
        })?;
        Ok(CoarseDensity(levels))
    }
}

/// The coarse solve as the slabs need it; the coarse tree is rebuilt from `refined`.
pub(crate) struct CoarseRecord {
    pub refined: Vec<Vec<u64>>,
    pub x: Vec<Vec<f32>>,
    pub p: Vec<Vec<f32>>,
    pub base_level: u32,
    pub carry: Carry,
    pub mean_area: f64,
    pub mean_depth: f64,
    /// Samples of all slabs (for the statistics).
    pub samples: u64,
}

impl Record for CoarseRecord {
    const TAG: &'static [u8; 8] = b"spsrCRS1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        put_levels_u64(o, &self.refined)?;
        put_levels_f32(o, &self.x)?;
        put_levels_f32(o, &self.p)?;
        o.u32(self.base_level)?;
        o.u32(self.carry.level)?;
        o.list(&self.carry.p, |o, &x| o.f64(x))?;
        o.list(&self.carry.vc, |o, &v| put3_f32(o, v))?;
        o.f64(self.mean_area)?;
        o.f64(self.mean_depth)?;
        o.u64(self.samples)
    }
    fn get(i: &mut In) -> Result<Self> {
        Ok(CoarseRecord {
            refined: get_levels_u64(i)?,
            x: get_levels_f32(i)?,
            p: get_levels_f32(i)?,
            base_level: i.u32()?,
            carry: Carry {
                level: i.u32()?,
                p: i.list(8, In::f64)?,
                vc: i.list(12, get3_f32)?,
            },
            mean_area: i.f64()?,
            mean_depth: i.f64()?,
            samples: i.u64()?,
        })
    }
}

/// The histogram of the depths at which a slab's samples' noise was measured.
pub(crate) struct Histogram(pub Vec<u64>);

impl Record for Histogram {
    const TAG: &'static [u8; 8] = b"spsrNOI1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.list(&self.0, |o, &c| o.u64(c))
    }
    fn get(i: &mut In) -> Result<Self> {
        i.list(8, In::u64).map(Histogram)
    }
}

/// A slab's samples (its own and its padding's), kept between its phases.
impl Record for SlabSamples {
    const TAG: &'static [u8; 8] = b"spsrSMP5";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.list(&self.samples, |o, x| {
            x.pos.iter().try_for_each(|&c| o.f64(c))?;
            o.f64(x.weight)?;
            x.normal.iter().try_for_each(|&c| o.f64(c))
        })?;
        o.list(&self.depths, |o, q| {
            o.f64(q.depth)?;
            o.f64(q.area)?;
            o.f64(q.screen)?;
            o.u32(q.screen_depth)
        })?;
        o.list(&self.measured, |o, m| match m {
            Some(m) => {
                o.u32(m.depth)?;
                o.f64(m.sigma)?;
                o.f64(m.coarser)
            }
            None => o.u32(u32::MAX),
        })?;
        o.list(&self.values, |o, &v| o.f64(v))
    }
    fn get(i: &mut In) -> Result<Self> {
        let samples = i.list(56, |i| {
            Ok(Sample {
                pos: [i.f64()?, i.f64()?, i.f64()?],
                weight: i.f64()?,
                normal: [i.f64()?, i.f64()?, i.f64()?],
            })
        })?;
        let depths = i.list(28, |i| {
            Ok(DepthAndArea {
                depth: i.f64()?,
                area: i.f64()?,
                screen: i.f64()?,
                screen_depth: i.u32()?,
            })
        })?;
        let measured = i.list(4, |i| {
            let d = i.u32()?;
            if d == u32::MAX {
                Ok(None)
            } else {
                Ok(Some(noise::MeasuredNoise {
                    depth: d,
                    sigma: i.f64()?,
                    coarser: i.f64()?,
                }))
            }
        })?;
        let values = i.list(8, In::f64)?;
        if depths.len() != samples.len()
            || !(measured.is_empty() || measured.len() == samples.len())
        {
            return Err(i.bad("does not give every sample its depth"));
        }
        Ok(SlabSamples {
            samples,
            depths,
            measured,
            values,
        })
    }
}

/// The whole cloud's coarse levels between their cycles (`phases::cycle_coarse`): what
/// rebuilds their system (the tree's refined nodes, the screening clusters' merged sums) and
/// the cycles' state.
pub(crate) struct CoarseState {
    pub refined: Vec<Vec<u64>>,
    /// Per tree depth: the clusters' merged sums `(node, W, W·p)`.
    pub clusters: Vec<Vec<ClusterSum>>,
    pub mean_area: f64,
    pub mean_depth: f64,
    /// Samples of all slabs (for the statistics).
    pub samples: u64,
    pub cycles: CycleState,
}

impl Record for CoarseState {
    const TAG: &'static [u8; 8] = b"spsrCST1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        put_levels_u64(o, &self.refined)?;
        o.list(&self.clusters, |o, l| {
            o.list(l, |o, &(n, w, wp)| {
                o.u32(n)?;
                o.f64(w)?;
                put3_f64(o, wp)
            })
        })?;
        o.f64(self.mean_area)?;
        o.f64(self.mean_depth)?;
        o.u64(self.samples)?;
        let c = &self.cycles;
        put_levels_f32(o, &c.b)?;
        o.list(&c.b_base, |o, &x| o.f64(x))?;
        put_levels_f32(o, &c.x)?;
        o.list(&c.x_base, |o, &x| o.f64(x))?;
        o.list(&c.vc, |o, &v| put3_f32(o, v))
    }
    fn get(i: &mut In) -> Result<Self> {
        Ok(CoarseState {
            refined: get_levels_u64(i)?,
            clusters: i.list(8, |i| {
                i.list(36, |i| Ok((i.u32()?, i.f64()?, get3_f64(i)?)))
            })?,
            mean_area: i.f64()?,
            mean_depth: i.f64()?,
            samples: i.u64()?,
            cycles: CycleState {
                b: get_levels_f32(i)?,
                b_base: i.list(8, In::f64)?,
                x: get_levels_f32(i)?,
                x_base: i.list(8, In::f64)?,
                vc: i.list(12, get3_f32)?,
            },
        })
    }
}

/// What a slab's own finer nodes add to the gradient coupling `U` on the coarse level: the
/// node's key and the sum (`phases::solve`).
pub(crate) struct Coupling(pub Vec<([u32; 3], f64)>);

impl Record for Coupling {
    const TAG: &'static [u8; 8] = b"spsrCPL1";
    fn put(&self, o: &mut Out) -> std::io::Result<()> {
        o.list(&self.0, |o, &(k, u)| {
            o.key(k)?;
            o.f64(u)
        })
    }
    fn get(i: &mut In) -> Result<Self> {
        i.list(20, |i| Ok((i.key()?, i.f64()?))).map(Coupling)
    }
}
