//! Copies between host arrays and the card through page-locked staging buffers.
//!
//! A copy from ordinary (pageable) memory makes the driver copy it once more, on one CPU
//! thread, into a page-locked buffer of its own, and a copy into a freshly allocated `Vec`
//! also takes its page faults on that thread: on the H200 the solver's copies ran at
//! 1.4–2 GB/s, a twentieth of the bus. Here a large copy is cut into pieces that every CPU
//! thread copies at once into one of two page-locked buffers while the card's copy engine
//! moves the other, so that the bus, not one thread, sets the pace. Small copies go straight.

use std::ptr::NonNull;
use std::sync::{Arc, Mutex, MutexGuard, TryLockError};

use cudarc::driver::{
    result, CudaEvent, CudaSlice, CudaStream, DevicePtr, DevicePtrMut, DeviceRepr, DriverError,
};
use rayon::prelude::*;

/// Bytes of each staging buffer.
const PIECE: usize = 32 << 20;
/// Copies of fewer bytes go straight from (or to) the host array.
const DIRECT: usize = 1 << 20;
/// Bytes each CPU thread copies at a time.
const STRIDE: usize = 256 << 10;

/// The two staging buffers, allocated on the first large copy.
#[derive(Default)]
pub(super) struct Staging {
    bufs: Mutex<Option<[Pinned; 2]>>,
}

/// The staging buffers, held by one copy.
type Buffers<'a> = MutexGuard<'a, Option<[Pinned; 2]>>;

/// One page-locked buffer of [`PIECE`] bytes, and the event recorded after the last copy
/// that used it.
struct Pinned {
    ptr: NonNull<u8>,
    done: CudaEvent,
}

// SAFETY: the buffer is ordinary host memory owned by this value alone; the driver only
// reads or writes it during copies that `done` marks, which every use waits for.
unsafe impl Send for Pinned {}

impl Pinned {
    fn new(stream: &Arc<CudaStream>) -> Result<Pinned, DriverError> {
        let done = stream.context().new_event(None)?;
        // SAFETY: a plain page-locked allocation (not write-combined: the CPU also reads it
        // back); freed in `drop`.
        let ptr = unsafe { result::malloc_host(PIECE, 0) }?;
        let ptr = NonNull::new(ptr.cast::<u8>()).ok_or(DriverError(
            cudarc::driver::sys::cudaError_enum::CUDA_ERROR_OUT_OF_MEMORY,
        ))?;
        Ok(Pinned { ptr, done })
    }

    /// The buffer's first `len` bytes, once the last copy through it is over.
    fn wait(&mut self, len: usize) -> Result<&mut [u8], DriverError> {
        self.done.synchronize()?;
        debug_assert!(len <= PIECE);
        // SAFETY: `PIECE` bytes were allocated and no copy uses them any more.
        Ok(unsafe { std::slice::from_raw_parts_mut(self.ptr.as_ptr(), len.min(PIECE)) })
    }
}

impl Drop for Pinned {
    fn drop(&mut self) {
        let _ = self.done.synchronize();
        // SAFETY: allocated by `malloc_host`, and no copy uses it any more.
        let _ = unsafe { result::free_host(self.ptr.as_ptr().cast()) };
    }
}

impl Staging {
    /// Copies `host` to a new device array (one element when empty: CUDA allocates no
    /// zero-size arrays, and the kernels never read an empty one).
    pub(super) fn upload<T: DeviceRepr + Default + Clone>(
        &self,
        s: &Arc<CudaStream>,
        host: &[T],
    ) -> Result<CudaSlice<T>, DriverError> {
        if host.is_empty() {
            return s.clone_htod(&[T::default()][..]);
        }
        let bytes = as_bytes(host);
        if bytes.len() < DIRECT {
            return s.clone_htod(host);
        }
        let Some(mut guard) = self.buffers(s)? else {
            return s.clone_htod(host);
        };
        // SAFETY: every byte is written below before any kernel reads it.
        let mut dev = unsafe { s.alloc::<T>(host.len()) }?;
        let bufs = guard.as_mut().expect("allocated by `buffers`");
        {
            let (dst, _written) = dev.device_ptr_mut(s);
            for (i, piece) in bytes.chunks(PIECE).enumerate() {
                let buf = &mut bufs[i % 2];
                let stage = buf.wait(piece.len())?;
                copy(stage, piece);
                // SAFETY: `dst` holds `bytes.len()` bytes, and this piece lies inside them;
                // the staging buffer is not touched again before `done` says the copy is over.
                unsafe {
                    result::memcpy_htod_async(dst + (i * PIECE) as u64, stage, s.cu_stream())
                }?;
                buf.done.record(s)?;
            }
        }
        Ok(dev)
    }

    /// The first `len` values of a device array.
    pub(super) fn download<T: DeviceRepr + Default + Clone>(
        &self,
        s: &Arc<CudaStream>,
        dev: &CudaSlice<T>,
        len: usize,
    ) -> Result<Vec<T>, DriverError> {
        let mut out = vec![T::default(); len];
        self.download_into(s, dev, &mut out)?;
        Ok(out)
    }

    /// The first `out.len()` values of a device array, into `out`.
    pub(super) fn download_into<T: DeviceRepr + Default + Clone>(
        &self,
        s: &Arc<CudaStream>,
        dev: &CudaSlice<T>,
        out: &mut [T],
    ) -> Result<(), DriverError> {
        if out.is_empty() {
            return Ok(());
        }
        let guard = match std::mem::size_of_val(out) < DIRECT {
            true => None,
            false => self.buffers(s)?,
        };
        let Some(mut guard) = guard else {
            s.memcpy_dtoh(&dev.slice(0..out.len()), out)?;
            return s.synchronize();
        };
        let bytes = as_bytes_mut(out);
        let total = bytes.len();
        let bufs = guard.as_mut().expect("allocated by `buffers`");
        let (src, _read) = dev.device_ptr(s);
        let pieces = total.div_ceil(PIECE);
        let piece = |i: usize| i * PIECE..((i + 1) * PIECE).min(total);
        // Piece `i` goes into buffer `i % 2`; the next one is on its way while one is copied
        // out.
        let start = |i: usize, bufs: &mut [Pinned; 2]| -> Result<(), DriverError> {
            let r = piece(i);
            let buf = &mut bufs[i % 2];
            let stage = buf.wait(r.len())?;
            // SAFETY: the device array holds `total` bytes and the piece lies inside them;
            // the staging buffer is read only after `done` says the copy is over.
            unsafe { result::memcpy_dtoh_async(stage, src + r.start as u64, s.cu_stream()) }?;
            buf.done.record(s)
        };
        start(0, bufs)?;
        for i in 0..pieces {
            if i + 1 < pieces {
                start(i + 1, bufs)?;
            }
            let r = piece(i);
            let stage = bufs[i % 2].wait(r.len())?;
            copy(&mut bytes[r], stage);
        }
        Ok(())
    }

    /// The staging buffers, allocated on first use; `None` while another copy holds them.
    /// The copies into and out of them run on rayon's threads, which may meanwhile pick up
    /// other work; were that work to copy too, waiting here would never end, so it goes
    /// straight instead.
    fn buffers(&self, s: &Arc<CudaStream>) -> Result<Option<Buffers<'_>>, DriverError> {
        let mut guard = match self.bufs.try_lock() {
            Ok(g) => g,
            Err(TryLockError::Poisoned(e)) => e.into_inner(),
            Err(TryLockError::WouldBlock) => return Ok(None),
        };
        if guard.is_none() {
            *guard = Some([Pinned::new(s)?, Pinned::new(s)?]);
        }
        Ok(Some(guard))
    }
}

/// `dst = src`, every CPU thread copying its own stretch.
fn copy(dst: &mut [u8], src: &[u8]) {
    dst.par_chunks_mut(STRIDE)
        .zip(src.par_chunks(STRIDE))
        .for_each(|(d, s)| d.copy_from_slice(s));
}

/// The bytes of a slice of device values.
fn as_bytes<T: DeviceRepr>(v: &[T]) -> &[u8] {
    // SAFETY: the values the kernels read are plain numbers and arrays of them (`DeviceRepr`),
    // with no padding, so every byte is initialised; the view covers exactly the slice.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), std::mem::size_of_val(v)) }
}

/// The bytes of a mutable slice of device values.
fn as_bytes_mut<T: DeviceRepr>(v: &mut [T]) -> &mut [u8] {
    // SAFETY: as in `as_bytes`; moreover any bytes written form valid values of these plain
    // number types, since they are copies of values of the same type on the card.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast(), std::mem::size_of_val(v)) }
}

#[cfg(test)]
mod tests {
    use super::{Staging, DIRECT, PIECE};
    use cudarc::driver::CudaContext;

    /// Arrays of every size class (empty, direct, one piece, several with a short last one)
    /// come back from the card as they went; skipped, with a message, without a GPU.
    #[test]
    fn copies_through_the_staging_buffers_round_trip() {
        // SAFETY: only probes whether the shared library can be loaded.
        let present = unsafe { cudarc::driver::sys::is_culib_present() };
        let ctx = match present.then(|| CudaContext::new(0)) {
            Some(Ok(ctx)) => ctx,
            _ => {
                eprintln!("skipped: no CUDA device here");
                return;
            }
        };
        let s = ctx.default_stream();
        let staging = Staging::default();
        for len in [
            0,
            3,
            DIRECT / 8 + 1,
            PIECE / 8,
            2 * PIECE / 8 + PIECE / 16 + 5,
        ] {
            let host: Vec<f64> = (0..len).map(|i| i as f64 * 0.5 - 7.0).collect();
            let dev = staging.upload(&s, &host).expect("upload");
            let back = staging.download(&s, &dev, len).expect("download");
            assert!(back == host, "{len} values did not round-trip");
            let mut again = vec![1.0; len];
            staging
                .download_into(&s, &dev, &mut again)
                .expect("download_into");
            assert!(again == host, "{len} values did not round-trip in place");
        }
    }
}
