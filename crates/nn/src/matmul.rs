//! Matrix products of host slices into buffers written once, through the `gemm` crate with
//! the kernel call and parallelism rule of flex's `matmul`, so every value is flex's to the
//! bit (test).
//!
//! Why: flex's `matmul` makes its output as a zeroed byte buffer on the calling thread and
//! then copies it into aligned storage before the product overwrites it; the sparse
//! convolution's dozens of small per-offset products a layer paid those two passes each
//! (with the row gathers, a sixth of the DASANet CPU row's training step went to `memmove`
//! and `memset`). Here the product writes straight into the spare capacity of a new vector.

/// A row-major matrix in a slice, or a transposed view of one (no copy).
#[derive(Debug, Clone, Copy)]
pub struct MatrixRef<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

impl<'a> MatrixRef<'a> {
    /// `data` as a row-major [rows, cols] matrix.
    pub fn new(data: &'a [f32], [rows, cols]: [usize; 2]) -> Self {
        assert_eq!(data.len(), rows * cols, "a [{rows}, {cols}] matrix");
        Self {
            data,
            rows,
            cols,
            row_stride: cols,
            col_stride: 1,
        }
    }

    /// `data` as rows of `cols` values each.
    pub fn rows(data: &'a [f32], cols: usize) -> Self {
        Self::new(data, [data.len() / cols.max(1), cols])
    }

    /// The transpose, as a view of the same values.
    pub fn t(self) -> Self {
        Self {
            rows: self.cols,
            cols: self.rows,
            row_stride: self.col_stride,
            col_stride: self.row_stride,
            ..self
        }
    }
}

/// Products at least this large (m·n·k) run gemm on rayon's threads: flex's threshold.
const PARALLEL_THRESHOLD: usize = 192 * 192 * 192;

/// `lhs · rhs` as a row-major [lhs.rows, rhs.cols] vector.
pub fn product(lhs: MatrixRef, rhs: MatrixRef) -> Vec<f32> {
    let len = lhs.rows * rhs.cols;
    let mut out = Vec::<f32>::with_capacity(len);
    // SAFETY: `gemm_into` writes all `len` values of the row-major [lhs.rows, rhs.cols]
    // output, which lies in `out`'s capacity, without reading them.
    unsafe {
        gemm_into(lhs, rhs, out.as_mut_ptr());
        out.set_len(len);
    }
    out
}

/// `lhs · rhs` written over `out`, a row-major [lhs.rows, rhs.cols] slice.
pub fn product_into(lhs: MatrixRef, rhs: MatrixRef, out: &mut [f32]) {
    assert_eq!(
        out.len(),
        lhs.rows * rhs.cols,
        "an output of the product's size"
    );
    // SAFETY: `out` holds the whole output.
    unsafe { gemm_into(lhs, rhs, out.as_mut_ptr()) }
}

/// Writes every value of the row-major [lhs.rows, rhs.cols] product at `out`, reading none.
///
/// # Safety
/// `out` must be valid for writes of lhs.rows · rhs.cols values.
unsafe fn gemm_into(lhs: MatrixRef, rhs: MatrixRef, out: *mut f32) {
    assert_eq!(lhs.cols, rhs.rows, "matching inner dimensions");
    let (m, k, n) = (lhs.rows, lhs.cols, rhs.cols);
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // SAFETY: the caller's promise.
        unsafe { std::ptr::write_bytes(out, 0, m * n) };
        return;
    }
    let parallelism = if m.saturating_mul(n).saturating_mul(k) >= PARALLEL_THRESHOLD {
        gemm::Parallelism::Rayon(0)
    } else {
        gemm::Parallelism::None
    };
    // SAFETY: both inputs are read within their slices (each view's largest index,
    // (rows − 1)·row_stride + (cols − 1)·col_stride, is below its slice's length by
    // construction); the output is m × n row-major at `out` (the caller's promise), and with
    // `read_dst` false gemm writes every one of its values without reading them.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out,
            1,
            n as isize,
            false,
            lhs.data.as_ptr(),
            lhs.col_stride as isize,
            lhs.row_stride as isize,
            rhs.data.as_ptr(),
            rhs.col_stride as isize,
            rhs.row_stride as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            parallelism,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::backend::Flex;
    use burn::backend::flex::FlexTensor;
    use burn::backend::ops::FloatTensorOps;
    use burn::prelude::*;

    fn filled(n: usize, salt: usize) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * 7919 + salt * 104_729) % 2003) as f32 / 1001.5 - 1.0)
            .collect()
    }

    fn flex(values: &[f32], shape: [usize; 2]) -> FlexTensor {
        FlexTensor::from_data(TensorData::new(values.to_vec(), shape))
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Products of plain and transposed views give flex's `matmul` values to the bit, below
    /// and above the size at which gemm runs on several threads, and for empty shapes.
    #[test]
    fn products_match_flex_matmul_bit_for_bit() {
        for [m, k, n] in [
            [1, 1, 1],
            [7, 3, 5],
            [300, 16, 32],
            [4000, 64, 64],
            [5, 0, 4],
            [0, 3, 2],
        ] {
            let (a, b) = (filled(m * k, 1), filled(k * n, 2));
            let expected = Flex::float_matmul(flex(&a, [m, k]), flex(&b, [k, n]));
            let got = product(MatrixRef::new(&a, [m, k]), MatrixRef::new(&b, [k, n]));
            let expected = expected.into_data().try_to_vec::<f32>().unwrap();
            assert_eq!(bits(&got), bits(&expected), "[{m}, {k}] · [{k}, {n}]");

            // The transposed views as flex's swapped axes: aᵀ ([k, m] stored) and bᵀ.
            let (at, bt) = (filled(k * m, 3), filled(n * k, 4));
            let swap = |t: FlexTensor| Flex::float_swap_dims(t, 0, 1);
            let expected = Flex::float_matmul(swap(flex(&at, [k, m])), swap(flex(&bt, [n, k])));
            let got = product(
                MatrixRef::new(&at, [k, m]).t(),
                MatrixRef::new(&bt, [n, k]).t(),
            );
            let expected = expected.into_data().try_to_vec::<f32>().unwrap();
            assert_eq!(
                bits(&got),
                bits(&expected),
                "transposed, [{m}, {k}] · [{k}, {n}]"
            );
        }
    }
}
