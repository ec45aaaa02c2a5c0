//! Borrowed and owned row-major images with a row stride.
//!
//! [`ImageView`] borrows camera buffers (with padding at the end of each row) without a copy; [`Image`] owns its
//! pixels and lends views. Pixels are `u8` or `u16` ([`Pixel`]).

use crate::CoreError;

/// A grey-level pixel type: 8- or 16-bit unsigned.
pub trait Pixel: Copy + Default + Ord + Send + Sync + std::fmt::Debug + 'static {
    /// The largest representable value.
    const MAX_VALUE: u16;
    /// The value as `f32`.
    fn to_f32(self) -> f32;
    /// The value as `u32`.
    fn to_u32(self) -> u32;
    /// Saturating conversion from a (rounded) `f32`.
    fn from_f32_saturating(v: f32) -> Self;
    /// Smallest value of a slice (`u32::MAX` when empty), reduced in the pixel type so that it vectorises.
    fn slice_min(s: &[Self]) -> u32;
    /// Index of the first value above `level`, if any: the dominant-peak scan's jump over background.
    fn first_above(s: &[Self], level: u32) -> Option<usize> {
        s.iter().position(|p| p.to_u32() > level)
    }
    /// The valley marks of the 16 pixels `s[i..i + 16]`: bit `k` is set when pixel `i + k` is inside the line and
    /// at most both its neighbours (an end pixel: at most its one neighbour). These are the candidates for the
    /// valleys that bound a dominant peak's region of interest, tested 16 at a time instead of by a walk per peak.
    fn valley_marks(s: &[Self], i: usize) -> u32 {
        valley_marks_scalar(s, i)
    }
}

/// The portable [`Pixel::valley_marks`].
fn valley_marks_scalar<T: Pixel>(s: &[T], i: usize) -> u32 {
    let n = s.len();
    let mut m = 0;
    for k in 0..16 {
        let j = i + k;
        if j >= n {
            break;
        }
        let x = s[j];
        let left = j == 0 || s[j - 1] >= x;
        let right = j + 1 >= n || s[j + 1] >= x;
        m |= u32::from(left && right) << k;
    }
    m
}

impl Pixel for u8 {
    const MAX_VALUE: u16 = u8::MAX as u16;
    #[inline]
    fn to_f32(self) -> f32 {
        f32::from(self)
    }
    #[inline]
    fn to_u32(self) -> u32 {
        u32::from(self)
    }
    #[inline]
    fn from_f32_saturating(v: f32) -> Self {
        // `as` saturates and maps NaN to 0.
        v.round() as u8
    }
    #[inline]
    fn slice_min(s: &[Self]) -> u32 {
        s.iter().copied().min().map_or(u32::MAX, u32::from)
    }
    #[inline]
    fn first_above(s: &[Self], level: u32) -> Option<usize> {
        u8::try_from(level)
            .ok()
            .and_then(|l| simd::first_above_u8(s, l))
    }
    #[inline]
    fn valley_marks(s: &[Self], i: usize) -> u32 {
        simd::valley_marks_u8(s, i).unwrap_or_else(|| valley_marks_scalar(s, i))
    }
}

impl Pixel for u16 {
    const MAX_VALUE: u16 = u16::MAX;
    #[inline]
    fn to_f32(self) -> f32 {
        f32::from(self)
    }
    #[inline]
    fn to_u32(self) -> u32 {
        u32::from(self)
    }
    #[inline]
    fn from_f32_saturating(v: f32) -> Self {
        v.round() as u16
    }
    #[inline]
    fn slice_min(s: &[Self]) -> u32 {
        s.iter().copied().min().map_or(u32::MAX, u32::from)
    }
    #[inline]
    fn first_above(s: &[Self], level: u32) -> Option<usize> {
        u16::try_from(level)
            .ok()
            .and_then(|l| simd::first_above_u16(s, l))
    }
    #[inline]
    fn valley_marks(s: &[Self], i: usize) -> u32 {
        simd::valley_marks_u16(s, i).unwrap_or_else(|| valley_marks_scalar(s, i))
    }
}

/// The search for the first pixel above a level, 16 bytes at a time.
///
/// Measured hot spot: in the dominant-peak scan, jumping over the background between stripes one pixel at a time
/// was the largest single cost of a frame (a compare and a branch per pixel, `position` does not vectorise because
/// of its early exit). On x86-64, SSE2 (part of the baseline, so no run-time detection) compares 16 (8-bit) or 8
/// (16-bit) pixels per step: a saturating subtraction of the level is non-zero exactly where a pixel exceeds it, and
/// a byte mask of the zero lanes finds the first. Elsewhere the portable loop. Tested against `position` on random
/// lines, every level and offset.
///
/// The valley marks ([`Pixel::valley_marks`]) likewise: a pixel is at most both neighbours exactly where the
/// saturating subtractions of the two neighbours from it are both zero, 16 pixels in one step (8-bit) or two
/// (16-bit); blocks touching a line's end pixels go the scalar way. Tested against the scalar marks on random lines
/// of every length, at every offset.
#[allow(unsafe_code)]
mod simd {
    #[cfg(target_arch = "x86_64")]
    #[inline]
    pub fn valley_marks_u8(s: &[u8], i: usize) -> Option<u32> {
        use std::arch::x86_64::{
            __m128i, _mm_cmpeq_epi8, _mm_loadu_si128, _mm_movemask_epi8, _mm_or_si128,
            _mm_setzero_si128, _mm_subs_epu8,
        };
        if i == 0 || i + 16 >= s.len() {
            return None;
        }
        // SAFETY: SSE2 is part of the x86-64 baseline; the loads read s[i - 1..i + 15], s[i..i + 16] and
        // s[i + 1..i + 17], inside the slice since i >= 1 and i + 16 < s.len(); unaligned loads are allowed.
        unsafe {
            let p = s.as_ptr().add(i);
            let prev = _mm_loadu_si128(p.sub(1).cast::<__m128i>());
            let cur = _mm_loadu_si128(p.cast::<__m128i>());
            let next = _mm_loadu_si128(p.add(1).cast::<__m128i>());
            let above = _mm_or_si128(_mm_subs_epu8(cur, prev), _mm_subs_epu8(cur, next));
            Some(_mm_movemask_epi8(_mm_cmpeq_epi8(above, _mm_setzero_si128())) as u32 & 0xffff)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    pub fn valley_marks_u16(s: &[u16], i: usize) -> Option<u32> {
        use std::arch::x86_64::{
            __m128i, _mm_cmpeq_epi16, _mm_loadu_si128, _mm_movemask_epi8, _mm_or_si128,
            _mm_packs_epi16, _mm_setzero_si128, _mm_subs_epu16,
        };
        if i == 0 || i + 16 >= s.len() {
            return None;
        }
        // SAFETY: as above, two blocks of 8 pixels of 16 bits, reading s[i - 1..i + 17].
        unsafe {
            let zero = _mm_setzero_si128();
            let block = |p: *const u16| {
                let prev = _mm_loadu_si128(p.sub(1).cast::<__m128i>());
                let cur = _mm_loadu_si128(p.cast::<__m128i>());
                let next = _mm_loadu_si128(p.add(1).cast::<__m128i>());
                let above = _mm_or_si128(_mm_subs_epu16(cur, prev), _mm_subs_epu16(cur, next));
                _mm_cmpeq_epi16(above, zero)
            };
            let p = s.as_ptr().add(i);
            // Packing the two blocks' 16-bit lanes (0 or -1) to bytes leaves one mask bit per pixel.
            let lanes = _mm_packs_epi16(block(p), block(p.add(8)));
            Some(_mm_movemask_epi8(lanes) as u32 & 0xffff)
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub fn valley_marks_u8(_: &[u8], _: usize) -> Option<u32> {
        None
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub fn valley_marks_u16(_: &[u16], _: usize) -> Option<u32> {
        None
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    pub fn first_above_u8(s: &[u8], level: u8) -> Option<usize> {
        use std::arch::x86_64::{
            __m128i, _mm_cmpeq_epi8, _mm_loadu_si128, _mm_movemask_epi8, _mm_set1_epi8,
            _mm_setzero_si128, _mm_subs_epu8,
        };
        let mut i = 0;
        // SAFETY: SSE2 is part of the x86-64 baseline; every load reads 16 bytes at `i` with `i + 16 <= s.len()`,
        // unaligned loads are allowed.
        unsafe {
            let lv = _mm_set1_epi8(level as i8);
            let zero = _mm_setzero_si128();
            while i + 16 <= s.len() {
                let v = _mm_loadu_si128(s.as_ptr().add(i).cast::<__m128i>());
                let at_most = _mm_cmpeq_epi8(_mm_subs_epu8(v, lv), zero);
                let above = !(_mm_movemask_epi8(at_most) as u32) & 0xffff;
                if above != 0 {
                    return Some(i + above.trailing_zeros() as usize);
                }
                i += 16;
            }
        }
        s[i..].iter().position(|&p| p > level).map(|k| i + k)
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    pub fn first_above_u16(s: &[u16], level: u16) -> Option<usize> {
        use std::arch::x86_64::{
            __m128i, _mm_cmpeq_epi16, _mm_loadu_si128, _mm_movemask_epi8, _mm_set1_epi16,
            _mm_setzero_si128, _mm_subs_epu16,
        };
        let mut i = 0;
        // SAFETY: as above, 8 pixels of 16 bits per load with `i + 8 <= s.len()`.
        unsafe {
            let lv = _mm_set1_epi16(level as i16);
            let zero = _mm_setzero_si128();
            while i + 8 <= s.len() {
                let v = _mm_loadu_si128(s.as_ptr().add(i).cast::<__m128i>());
                let at_most = _mm_cmpeq_epi16(_mm_subs_epu16(v, lv), zero);
                // Two mask bits per 16-bit lane.
                let above = !(_mm_movemask_epi8(at_most) as u32) & 0xffff;
                if above != 0 {
                    return Some(i + above.trailing_zeros() as usize / 2);
                }
                i += 8;
            }
        }
        s[i..].iter().position(|&p| p > level).map(|k| i + k)
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub fn first_above_u8(s: &[u8], level: u8) -> Option<usize> {
        s.iter().position(|&p| p > level)
    }

    #[cfg(not(target_arch = "x86_64"))]
    pub fn first_above_u16(s: &[u16], level: u16) -> Option<usize> {
        s.iter().position(|&p| p > level)
    }
}

/// A borrowed row-major image: `height` rows of `width` pixels, each row starting `stride` pixels after the last.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a, T> {
    data: &'a [T],
    width: usize,
    height: usize,
    stride: usize,
}

impl<'a, T: Pixel> ImageView<'a, T> {
    /// Borrows `data` as an image. The last row need not be padded to the full stride.
    ///
    /// ```
    /// # use stripe3d_core::ImageView;
    /// let buffer = [1u8, 2, 3, 0, 4, 5, 6, 0];
    /// let view = ImageView::new(&buffer, 3, 2, 4).unwrap();
    /// assert_eq!(view.row(1), &[4, 5, 6]);
    /// ```
    pub fn new(
        data: &'a [T],
        width: usize,
        height: usize,
        stride: usize,
    ) -> Result<Self, CoreError> {
        if stride < width {
            return Err(CoreError::StrideTooSmall { stride, width });
        }
        let needed = if height == 0 {
            0
        } else {
            (height - 1) * stride + width
        };
        if data.len() < needed {
            return Err(CoreError::BufferTooSmall {
                len: data.len(),
                width,
                height,
                stride,
                needed,
            });
        }
        Ok(Self {
            data,
            width,
            height,
            stride,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row stride in pixels.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Row `y` as a slice of `width` pixels. Panics when `y >= height` (a programming error, not an input error).
    #[inline]
    pub fn row(&self, y: usize) -> &'a [T] {
        assert!(
            y < self.height,
            "row {y} out of range (height {})",
            self.height
        );
        &self.data[y * self.stride..y * self.stride + self.width]
    }

    /// The pixel at column `x`, row `y`, or `None` outside the image.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Option<T> {
        if x < self.width && y < self.height {
            self.data.get(y * self.stride + x).copied()
        } else {
            None
        }
    }
}

/// An owned row-major image without padding.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    data: Vec<T>,
    width: usize,
    height: usize,
}

impl<T: Pixel> Image<T> {
    /// A `width` x `height` image of zeros.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            data: vec![T::default(); width * height],
            width,
            height,
        }
    }

    /// Takes ownership of `data` (row-major, no padding).
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, CoreError> {
        let needed = width * height;
        if data.len() != needed {
            return Err(CoreError::BufferTooSmall {
                len: data.len(),
                width,
                height,
                stride: width,
                needed,
            });
        }
        Ok(Self {
            data,
            width,
            height,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The pixels, row-major.
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// The pixels, row-major, mutable.
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Consumes the image and returns its pixels.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// A borrowed view of the whole image.
    pub fn view(&self) -> ImageView<'_, T> {
        ImageView {
            data: &self.data,
            width: self.width,
            height: self.height,
            stride: self.width,
        }
    }

    /// The pixel at column `x`, row `y`, or `None` outside the image.
    pub fn get(&self, x: usize, y: usize) -> Option<T> {
        self.view().get(x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_with_stride_reads_rows_and_refuses_short_buffers() {
        let data: Vec<u16> = (0..11).collect();
        let v = ImageView::new(&data, 3, 3, 4).expect("fits");
        assert_eq!(v.row(0), &[0, 1, 2]);
        assert_eq!(v.row(2), &[8, 9, 10]);
        assert_eq!(v.get(2, 1), Some(6));
        assert_eq!(v.get(3, 1), None);
        assert_eq!(v.get(0, 3), None);
        assert!(matches!(
            ImageView::new(&data[..10], 3, 3, 4),
            Err(CoreError::BufferTooSmall { needed: 11, .. })
        ));
        assert!(matches!(
            ImageView::new(&data, 4, 1, 3),
            Err(CoreError::StrideTooSmall { .. })
        ));
        assert!(ImageView::<u8>::new(&[], 0, 0, 0).is_ok());
    }

    #[test]
    fn owned_image_checks_its_length() {
        assert!(Image::<u8>::from_vec(2, 2, vec![0; 3]).is_err());
        let img = Image::<u8>::from_vec(2, 2, vec![1, 2, 3, 4]).expect("fits");
        assert_eq!(img.view().row(1), &[3, 4]);
        assert_eq!(u8::from_f32_saturating(300.0), 255);
        assert_eq!(u16::from_f32_saturating(-3.0), 0);
    }

    #[test]
    fn first_above_finds_what_position_finds() {
        let mut next = crate::test_rng(0x2545_f491u32);
        for len in [0usize, 1, 7, 8, 15, 16, 17, 31, 33, 100, 648] {
            for _ in 0..40 {
                // Sparse bright pixels over a low background, so that every position of the first hit occurs.
                let v8: Vec<u8> = (0..len)
                    .map(|_| {
                        if next() % 23 == 0 {
                            (next() % 256) as u8
                        } else {
                            (next() % 12) as u8
                        }
                    })
                    .collect();
                let v16: Vec<u16> = v8
                    .iter()
                    .map(|&p| (u16::from(p) * 257).saturating_add((next() % 2) as u16))
                    .collect();
                for level in [0u32, 5, 11, 12, 100, 254, 255, 256, 65534, 65535, 70000] {
                    for from in [0usize, 1, 3, 9] {
                        let s = &v8[from.min(len)..];
                        assert_eq!(
                            u8::first_above(s, level),
                            s.iter().position(|&p| u32::from(p) > level)
                        );
                        let s = &v16[from.min(len)..];
                        assert_eq!(
                            u16::first_above(s, level),
                            s.iter().position(|&p| u32::from(p) > level)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn valley_marks_are_what_the_scalar_loop_marks() {
        let mut next = crate::test_rng(0x9e37_79b9u32);
        for len in (0usize..60).chain([647, 648]) {
            for _ in 0..10 {
                // Few levels, so that equal neighbours (flat valleys) are common.
                let v8: Vec<u8> = (0..len).map(|_| (next() % 4) as u8 * 85).collect();
                let v16: Vec<u16> = v8.iter().map(|&p| u16::from(p) * 257).collect();
                for i in 0..len + 2 {
                    let want = valley_marks_scalar(&v8, i);
                    assert_eq!(u8::valley_marks(&v8, i), want, "u8, {len} pixels, at {i}");
                    assert_eq!(
                        u16::valley_marks(&v16, i),
                        want,
                        "u16, {len} pixels, at {i}"
                    );
                }
            }
        }
    }
}
