//! `dst (+)= lhs · rhs` over strided `f32` slices with the `gemm` crate (candle's own kernel),
//! on the calling thread: the fused LSTM op and the fused MLP update multiply through here.

/// `dst[m×n] (+)= lhs[m×k] · rhs[k×n]`, each matrix given by its row and column strides.
pub struct MatMul {
    pub m: usize,
    pub n: usize,
    pub k: usize,
    pub accumulate: bool,
}

/// A matrix in a slice: `(slice, row stride, column stride)`.
pub type Strided<'a> = (&'a [f32], usize, usize);

impl MatMul {
    pub fn run(&self, dst: (&mut [f32], usize, usize), lhs: Strided<'_>, rhs: Strided<'_>) {
        let (m, n, k) = (self.m, self.n, self.k);
        if m == 0 || n == 0 {
            return;
        }
        let last = |rows: usize, cols: usize, rs: usize, cs: usize| (rows - 1) * rs + (cols - 1) * cs;
        assert!(dst.0.len() > last(m, n, dst.1, dst.2), "matmul: destination too short");
        if k > 0 {
            assert!(lhs.0.len() > last(m, k, lhs.1, lhs.2), "matmul: left operand too short");
            assert!(
                rhs.0.len() > last(k, n, rhs.1, rhs.2),
                "matmul: right operand too short"
            );
        }
        // SAFETY: the asserts above keep every element the strides address inside its slice; the
        // destination is borrowed mutably and the operands immutably, so they do not alias.
        unsafe {
            gemm::gemm(
                m,
                n,
                k,
                dst.0.as_mut_ptr(),
                dst.2 as isize,
                dst.1 as isize,
                self.accumulate,
                lhs.0.as_ptr(),
                lhs.2 as isize,
                lhs.1 as isize,
                rhs.0.as_ptr(),
                rhs.2 as isize,
                rhs.1 as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::None,
            );
        }
    }
}
