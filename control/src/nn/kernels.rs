//! Numeric kernels: a packed matrix-vector product, a packed 2-D convolution and branch-free
//! activation functions.
//!
//! Determinism contract: every output element is computed by the same sequence of IEEE-754 f32
//! operations in a fixed order, independent of SIMD width, so results are bit-identical on x86-64
//! and aarch64. The matrix-vector product uses separate multiplies and adds (Rust never contracts
//! `a * b + c`); the convolution uses fused multiply-adds (`f32::mul_add`: one rounding, exactly
//! specified by IEEE-754, so the FMA3 instruction on x86-64, NEON's `fmla` on aarch64 and a
//! correctly rounded software `fmaf` all give the same bits). No other libm function is called
//! (their results differ between platforms and libc versions). Speed comes from the layout
//! (independent output lanes), not from reassociating sums.

/// Output rows processed together: 32 independent accumulators (8 SSE / 4 AVX / 8 NEON
/// registers), enough to hide add latency while staying in registers on every target.
/// Measured on the peer policy (x86-64 baseline SSE2): 16 -> ~3.5 us/step, 32 -> ~2.5 us/step.
pub(crate) const BLOCK: usize = 32;

/// `y = W x + b` with `W` stored as row panels of [`BLOCK`] rows, column-major inside a panel.
///
/// Panel `p`, column `j` holds `W[p*BLOCK .. p*BLOCK+BLOCK][j]` contiguously, so the inner loop
/// is a broadcast of `x[j]` times one contiguous `[f32; BLOCK]` added into `BLOCK` accumulators.
/// The compiler vectorizes this across rows (no horizontal reductions), and each row's sum is
/// `b + W[r][0] x[0] + W[r][1] x[1] + ...` in exactly that order — the same as a naive loop.
/// Rows past `rows` in the last panel are zero padding and are never written out.
///
/// With AVX2 (detected at run time on x86-64) the same loop runs on 256-bit vectors, two panels
/// at a time (eight independent accumulator registers hide the add latency); every row's sum is
/// still the same sequence of operations, so the results are bit-identical.
#[derive(Clone)]
pub(crate) struct PackedMatrix {
    rows: usize,
    cols: usize,
    panels: Vec<[f32; BLOCK]>,
    bias: Vec<[f32; BLOCK]>,
    isa: Isa,
}

impl PackedMatrix {
    /// Packs a row-major `[rows, cols]` weight and a `[rows]` bias.
    /// Callers guarantee `weight.len() == rows * cols` and `bias.len() == rows`.
    pub(crate) fn pack(weight: &[f32], bias: &[f32], rows: usize, cols: usize) -> Self {
        let n_panels = rows.div_ceil(BLOCK);
        let mut panels = vec![[0.0f32; BLOCK]; n_panels * cols];
        let mut packed_bias = vec![[0.0f32; BLOCK]; n_panels];
        for r in 0..rows {
            let (p, lane) = (r / BLOCK, r % BLOCK);
            packed_bias[p][lane] = bias[r];
            for (j, &w) in weight[r * cols..(r + 1) * cols].iter().enumerate() {
                panels[p * cols + j][lane] = w;
            }
        }
        Self {
            rows,
            cols,
            panels,
            bias: packed_bias,
            isa: Isa::detect(),
        }
    }

    pub(crate) fn rows(&self) -> usize {
        self.rows
    }

    /// Selects the kernel, like [`PackedConv::set_isa`].
    pub(crate) fn set_isa(&mut self, isa: Isa) {
        if isa == Isa::Portable || isa == Isa::detect() {
            self.isa = isa;
        }
    }

    /// `y[..rows] = W x + b`. `x.len() == cols` and `y.len() == rows` are checked by the caller
    /// at load time; here they only bound the zips.
    #[inline]
    pub(crate) fn matvec(&self, x: &[f32], y: &mut [f32]) {
        debug_assert_eq!(x.len(), self.cols);
        debug_assert_eq!(y.len(), self.rows);
        match self.isa {
            Isa::Portable => self.matvec_panels::<false>(x, y),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::Avx2Fma` is only ever set from `Isa::detect()` (`pack` stores its
            // result, `set_isa` checks it), which checked at run time that this CPU supports AVX2.
            Isa::Avx2Fma => unsafe { self.matvec_avx2(x, y) },
        }
    }

    /// The AVX2 copy of [`Self::matvec_panels`], two panels at a time (separate multiplies and
    /// adds, never fused: the recorded policy logs replay bit-exact against this order).
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn matvec_avx2(&self, x: &[f32], y: &mut [f32]) {
        self.matvec_panels::<true>(x, y);
    }

    /// The product, panel by panel, or two panels side by side when `PAIRS` (more independent
    /// accumulators; needs the registers of AVX2 or wider).
    #[inline(always)]
    fn matvec_panels<const PAIRS: bool>(&self, x: &[f32], y: &mut [f32]) {
        let cols = self.cols;
        let x = &x[..cols];
        let mut panels = self.panels.chunks_exact(cols).zip(&self.bias).zip(y.chunks_mut(BLOCK));
        while let Some(((panel, bias), y_panel)) = panels.next() {
            let mut acc = *bias;
            if PAIRS {
                if let Some(((panel1, bias1), y_panel1)) = panels.next() {
                    let mut acc1 = *bias1;
                    for ((&xj, w), w1) in x.iter().zip(panel).zip(panel1) {
                        for k in 0..BLOCK {
                            acc[k] += w[k] * xj;
                        }
                        for k in 0..BLOCK {
                            acc1[k] += w1[k] * xj;
                        }
                    }
                    for (yk, ak) in y_panel.iter_mut().zip(acc) {
                        *yk = ak;
                    }
                    for (yk, ak) in y_panel1.iter_mut().zip(acc1) {
                        *yk = ak;
                    }
                    continue;
                }
            }
            for (&xj, w) in x.iter().zip(panel) {
                for k in 0..BLOCK {
                    acc[k] += w[k] * xj;
                }
            }
            for (yk, ak) in y_panel.iter_mut().zip(acc) {
                *yk = ak;
            }
        }
    }
}

/// Output channels per convolution weight panel: one AVX register, two SSE / NEON registers.
pub(crate) const CONV_LANES: usize = 8;

/// One tap's weights for [`CONV_LANES`] output channels. 32-byte aligned so that no load of a
/// panel entry straddles a cache line.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub(crate) struct Lanes(pub(crate) [f32; CONV_LANES]);

/// Output-channel panels a conv tile covers at once (16 channels); an odd last panel runs as
/// its own group. (Groups of three, 24 channels, need fewer instructions per multiply-add on
/// paper, but LLVM then hoists weight loads until AVX2's 16 registers spill: measured 1.8x
/// slower on the terrain CNN's conv3.)
const GROUP: usize = 2;

/// Tile widths (output pixels along a row) a kernel is compiled for, preferred first (see
/// [`pick_tile`]). A tile keeps `GROUP x P` accumulators in registers, and LLVM hoists the next
/// taps' weight loads (`GROUP x 3` registers for 3x3 kernels) above them; past the register file
/// it spills, which costs more than narrower tiles do. Measured on the terrain CNN (x86-64):
/// SSE2 (16 xmm, two per panel) 2 wide beats 3 wide (conv3 184 vs 304 us); AVX2 (16 ymm, one
/// per panel) 4 wide beats 5 wide (conv2 59 vs 67 us). NEON (32 registers, two per panel) gets
/// 4 wide (16 accumulators + 12 weights), not measured.
const TILES_PORTABLE: &[usize] = if cfg!(target_arch = "aarch64") {
    &[4, 3, 2]
} else {
    &[2, 3]
};
#[cfg(target_arch = "x86_64")]
const TILES_AVX2: &[usize] = &[4, 3, 2];
/// Widest tile of any kernel (sizes the slack after the padded input).
const TILE_MAX: usize = 4;

/// Geometry of a 2-D convolution (validated by the caller before [`PackedConv::pack`]):
/// `kh <= h + 2 pad`, `kw <= w + 2 pad`, `stride >= 1`, every size >= 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvGeom {
    pub(crate) cin: usize,
    pub(crate) h: usize,
    pub(crate) w: usize,
    pub(crate) cout: usize,
    pub(crate) kh: usize,
    pub(crate) kw: usize,
    pub(crate) stride: usize,
    pub(crate) pad: usize,
}

impl ConvGeom {
    /// Output height `(h + 2 pad - kh) / stride + 1`.
    pub(crate) fn ho(&self) -> usize {
        (self.h + 2 * self.pad - self.kh) / self.stride + 1
    }

    /// Output width `(w + 2 pad - kw) / stride + 1`.
    pub(crate) fn wo(&self) -> usize {
        (self.w + 2 * self.pad - self.kw) / self.stride + 1
    }

    /// Taps per output element, `cin * kh * kw`.
    pub(crate) fn taps(&self) -> usize {
        self.cin * self.kh * self.kw
    }
}

/// Which instruction set [`PackedConv::forward`] uses; all give bit-identical results.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Isa {
    Portable,
    /// AVX2 vectors; the convolution's multiply-adds are FMA3 instructions.
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Isa {
    /// The best kernel this CPU runs (AVX2 + FMA on x86-64 when present).
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            return Isa::Avx2Fma;
        }
        Isa::Portable
    }

    fn tiles(self) -> &'static [usize] {
        match self {
            Isa::Portable => TILES_PORTABLE,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2Fma => TILES_AVX2,
        }
    }
}

/// The tile width for output width `wo`: the first (most preferred) of `tiles` that wastes at
/// most a quarter of its pixel slots on the row (`ceil(wo / P) P - wo`), else the one that wastes
/// the fewest.
fn pick_tile(wo: usize, tiles: &[usize]) -> usize {
    let waste = |p: usize| wo.div_ceil(p) * p - wo;
    tiles
        .iter()
        .copied()
        .find(|&p| 4 * waste(p) <= wo.div_ceil(p) * p)
        .or_else(|| tiles.iter().copied().min_by_key(|&p| waste(p)))
        .unwrap_or(2)
}

/// Weights of groups of `NP` panels: group `i`, tap `t` holds `NP` panels of [`CONV_LANES`]
/// output channels, starting at panel `first + i NP`.
#[derive(Clone)]
struct PanelGroups<const NP: usize> {
    first: usize,
    /// `[n_groups * taps]`, group-major.
    w: Vec<[Lanes; NP]>,
    bias: Vec<[Lanes; NP]>,
}

impl<const NP: usize> PanelGroups<NP> {
    fn pack(g: &ConvGeom, weight: &[f32], bias: &[f32], first: usize, n_groups: usize) -> Self {
        let taps = g.taps();
        let mut w = vec![[Lanes::default(); NP]; n_groups * taps];
        let mut b = vec![[Lanes::default(); NP]; n_groups];
        for gi in 0..n_groups {
            for j in 0..NP {
                for lane in 0..CONV_LANES {
                    let co = (first + gi * NP + j) * CONV_LANES + lane;
                    if co >= g.cout {
                        continue;
                    }
                    b[gi][j].0[lane] = bias[co];
                    for (t, &v) in weight[co * taps..(co + 1) * taps].iter().enumerate() {
                        w[gi * taps + t][j].0[lane] = v;
                    }
                }
            }
        }
        Self { first, w, bias: b }
    }
}

/// A 2-D convolution (PyTorch `nn.Conv2d`, zero padding, CHW-flattened input and output) with
/// weights packed into panels of [`CONV_LANES`] output channels, in groups of [`GROUP`] panels.
///
/// Group `i`, tap `t = (ci * kh + ky) * kw + kx` holds the weights of output channels
/// `8 GROUP i .. 8 GROUP (i + 1)` for that tap contiguously (leftover panels form a last, smaller
/// group). A step copies the input into a zero-padded buffer (border and tail zeroed once, at
/// pack time), then walks each output row group by group, in tiles of `P` pixels: a
/// `P x GROUP x LANES` block of accumulators runs over the taps, per tap one weight load per
/// panel and one broadcast of the input per pixel, read straight from the padded input. For 3x3
/// kernels with stride 1 or 2 (compile-time constants) the `3 + (P - 1) * stride` inputs of a
/// kernel row are one fixed-size array, so the nine taps of an input channel run without a
/// single bounds check; other shapes take a generic loop (one check per tap). No im2col copy, no
/// padding branches. A following ReLU can be applied by the store ([`PackedConv::fuse_relu`]).
///
/// Determinism: every output element is `bias + w[t0] x[t0] + w[t1] x[t1] + ...` over all taps in
/// `(ci, ky, kx)` order, padding taps included (they add `w * 0`), exactly like a naive loop, for
/// any tile width, loop variant and instruction set. Lanes past `cout` in the last panel and
/// pixels past the row end in the last tile are computed on padding and never written out.
#[derive(Clone)]
pub(crate) struct PackedConv {
    g: ConvGeom,
    /// Padded input height and width.
    hp: usize,
    wp: usize,
    /// Full groups, then the remainder (at most one of `rest2`, `rest1` is non-empty; `rest2`
    /// only if [`GROUP`] is 3).
    groups: PanelGroups<GROUP>,
    rest2: PanelGroups<2>,
    rest1: PanelGroups<1>,
    /// Offset of tap `t` in the padded input, relative to the output pixel's top-left input.
    tap_off: Vec<usize>,
    /// Zero-padded input `[cin][hp][wp]`, then `TILE_MAX * stride` zeros of slack read by the
    /// last tile of the last row.
    xpad: Vec<f32>,
    isa: Isa,
    /// Tile width for `isa`.
    tile: usize,
    /// Apply ReLU (`x < 0 ? 0 : x`, as [`crate::nn::LayerDesc::Relu`]) while storing.
    relu: bool,
}

impl PackedConv {
    /// Packs a `[cout, cin, kh, kw]` weight and a `[cout]` bias for input `[cin, h, w]`.
    /// Callers guarantee the geometry is valid (see [`ConvGeom`]) and the lengths match.
    pub(crate) fn pack(g: ConvGeom, weight: &[f32], bias: &[f32], isa: Isa) -> Self {
        let taps = g.taps();
        let n_panels = g.cout.div_ceil(CONV_LANES);
        let (full, rest) = (n_panels / GROUP, n_panels % GROUP);
        let first_rest = full * GROUP;
        let (hp, wp) = (g.h + 2 * g.pad, g.w + 2 * g.pad);
        let mut tap_off = Vec::with_capacity(taps);
        for ci in 0..g.cin {
            for ky in 0..g.kh {
                for kx in 0..g.kw {
                    tap_off.push((ci * hp + ky) * wp + kx);
                }
            }
        }
        Self {
            g,
            hp,
            wp,
            groups: PanelGroups::pack(&g, weight, bias, 0, full),
            rest2: PanelGroups::pack(&g, weight, bias, first_rest, usize::from(rest == 2)),
            rest1: PanelGroups::pack(&g, weight, bias, first_rest, usize::from(rest == 1)),
            tap_off,
            xpad: vec![0.0; g.cin * hp * wp + TILE_MAX * g.stride],
            isa,
            tile: pick_tile(g.wo(), isa.tiles()),
            relu: false,
        }
    }

    /// Makes `forward` apply ReLU to its output (a following `relu` layer is then skipped).
    /// The same comparison as the separate layer, so the results are bit-identical.
    pub(crate) fn fuse_relu(&mut self) {
        self.relu = true;
    }

    pub(crate) fn geom(&self) -> &ConvGeom {
        &self.g
    }

    /// Output length `cout * ho * wo`.
    pub(crate) fn output_len(&self) -> usize {
        self.g.cout * self.g.ho() * self.g.wo()
    }

    /// Selects the kernel (tests and benchmarks compare them). Anything but `Portable` is taken
    /// only if [`Isa::detect`] returns it, so `forward` never runs an instruction set the CPU
    /// lacks.
    pub(crate) fn set_isa(&mut self, isa: Isa) {
        if isa == Isa::Portable || isa == Isa::detect() {
            self.isa = isa;
            self.tile = pick_tile(self.g.wo(), isa.tiles());
        }
    }

    /// Forces a tile width of the current instruction set (tests cover every compiled width).
    #[cfg(test)]
    pub(crate) fn set_tile(&mut self, tile: usize) {
        if self.isa.tiles().contains(&tile) {
            self.tile = tile;
        }
    }

    /// `y = conv(x)`: `x` is `[cin, h, w]`, `y` is `[cout, ho, wo]`, both CHW-flattened; lengths
    /// are checked by the caller at load time.
    pub(crate) fn forward(&mut self, x: &[f32], y: &mut [f32]) {
        debug_assert_eq!(x.len(), self.g.cin * self.g.h * self.g.w);
        debug_assert_eq!(y.len(), self.output_len());
        self.pad_input(x);
        let args = ConvArgs {
            g: &self.g,
            hp: self.hp,
            wp: self.wp,
            groups: &self.groups,
            rest2: &self.rest2,
            rest1: &self.rest1,
            tap_off: &self.tap_off,
            xpad: &self.xpad,
            relu: self.relu,
        };
        match self.isa {
            Isa::Portable => conv_dispatch(&args, self.tile, y),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::Avx2Fma` is only ever set from `Isa::detect()` (`pack` is given its
            // result, `set_isa` checks it), which checked at run time that this CPU supports AVX2
            // and FMA.
            Isa::Avx2Fma => unsafe { conv_avx2(&args, self.tile, y) },
        }
    }

    /// Copies `x` into the interior of the zero-padded buffer (border and slack never written).
    fn pad_input(&mut self, x: &[f32]) {
        let (h, w, p, wp) = (self.g.h, self.g.w, self.g.pad, self.wp);
        let plane_p = self.hp * wp;
        for (src_plane, dst_plane) in x.chunks_exact(h * w).zip(self.xpad.chunks_exact_mut(plane_p)) {
            for (src_row, dst_row) in src_plane.chunks_exact(w).zip(dst_plane[p * wp..].chunks_exact_mut(wp)) {
                dst_row[p..p + w].copy_from_slice(src_row);
            }
        }
    }
}

/// What the kernels read.
struct ConvArgs<'a> {
    g: &'a ConvGeom,
    hp: usize,
    wp: usize,
    groups: &'a PanelGroups<GROUP>,
    rest2: &'a PanelGroups<2>,
    rest1: &'a PanelGroups<1>,
    tap_off: &'a [usize],
    xpad: &'a [f32],
    relu: bool,
}

/// The AVX2 copy of [`conv_dispatch`]: the same code, compiled with 256-bit vectors and FMA3
/// instructions for its `mul_add`s (the portable copy computes the same fused results: NEON
/// `fmla` on aarch64, software `fmaf` on an x86-64 without FMA), so results are bit-identical.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn conv_avx2(a: &ConvArgs<'_>, tile: usize, y: &mut [f32]) {
    conv_dispatch(a, tile, y);
}

/// Monomorphizes the row loop for the tile width `P`; for 3x3 kernels also for stride 1 and 2,
/// with `L = 3 + (P - 1) * stride` inputs per kernel row.
#[inline(always)]
fn conv_dispatch(a: &ConvArgs<'_>, tile: usize, y: &mut [f32]) {
    let k3 = a.g.kh == 3 && a.g.kw == 3;
    macro_rules! variants {
        ($p:literal) => {
            match (k3, a.g.stride) {
                (true, 1) => conv_rows::<$p, 1, 3, { 3 + ($p - 1) }>(a, y),
                (true, 2) => conv_rows::<$p, 2, 3, { 3 + ($p - 1) * 2 }>(a, y),
                _ => conv_rows::<$p, 0, 0, 0>(a, y),
            }
        };
    }
    match tile {
        2 => variants!(2),
        3 => variants!(3),
        _ => variants!(4),
    }
}

/// The convolution, one output row at a time in tiles of `P` pixels (see [`PackedConv`]).
/// `K > 0`: a `K x K` kernel with stride `S` (`L = K + (P - 1) S`); `K = 0`: any geometry.
#[inline(always)]
fn conv_rows<const P: usize, const S: usize, const K: usize, const L: usize>(a: &ConvArgs<'_>, y: &mut [f32]) {
    let g = a.g;
    let s = g.stride;
    let (ho, wo) = (g.ho(), g.wo());
    for oy in 0..ho {
        let mut ox = 0;
        while ox < wo {
            let base = oy * s * a.wp + ox * s;
            let (pix, n) = (oy * wo + ox, P.min(wo - ox));
            row_tile::<GROUP, P, S, K, L>(a, a.groups, base, pix, n, y);
            row_tile::<2, P, S, K, L>(a, a.rest2, base, pix, n, y);
            row_tile::<1, P, S, K, L>(a, a.rest1, base, pix, n, y);
            ox += P;
        }
    }
}

/// `$body` for `$i` = 0, 1, .., `$n - 1` (`$n` <= [`TILE_MAX`], a constant), written out
/// straight: every `$i` is a literal, so accumulator arrays indexed by it stay in registers no
/// matter how LLVM's loop unroller sizes the body up.
macro_rules! unroll_tile {
    ($n:expr, $i:ident => $body:expr) => {{
        const _: () = assert!(TILE_MAX <= 6);
        {
            let $i = 0usize;
            if $i < $n {
                $body
            }
        }
        {
            let $i = 1usize;
            if $i < $n {
                $body
            }
        }
        {
            let $i = 2usize;
            if $i < $n {
                $body
            }
        }
        {
            let $i = 3usize;
            if $i < $n {
                $body
            }
        }
        {
            let $i = 4usize;
            if $i < $n {
                $body
            }
        }
        {
            let $i = 5usize;
            if $i < $n {
                $body
            }
        }
    }};
}

/// One tile of `P` pixels for every group of `grp`, stored.
#[inline(always)]
fn row_tile<const NP: usize, const P: usize, const S: usize, const K: usize, const L: usize>(
    a: &ConvArgs<'_>,
    grp: &PanelGroups<NP>,
    base: usize,
    pix: usize,
    n: usize,
    y: &mut [f32],
) {
    let (taps, g) = (a.tap_off.len(), a.g);
    let hw = g.ho() * g.wo();
    for (i, (w, b)) in grp.w.chunks_exact(taps).zip(&grp.bias).enumerate() {
        let acc = tile::<NP, P, S, K, L>(a, w, b, base);
        store(&acc, grp.first + i * NP, g.cout, hw, pix, n, a.relu, y);
    }
}

/// One tile: `acc[p][j] = bias_j + sum_t w[t][j] * x[base + off_t + p * stride]`, taps in order.
#[inline(always)]
fn tile<const NP: usize, const P: usize, const S: usize, const K: usize, const L: usize>(
    a: &ConvArgs<'_>,
    w: &[[Lanes; NP]],
    bias: &[Lanes; NP],
    base: usize,
) -> [[Lanes; NP]; P] {
    const { assert!(P >= 1 && P <= TILE_MAX) };
    let mut acc = [*bias; P];
    let x = a.xpad;
    if K > 0 {
        // K x K, stride S: per input channel, K rows of L inputs, each a fixed-size array.
        let plane = a.hp * a.wp;
        for (ci, wc) in w.chunks_exact(K * K).enumerate() {
            for ky in 0..K {
                let o = base + ci * plane + ky * a.wp;
                // Always in bounds (see `PackedConv::xpad`); `get` keeps even a broken invariant
                // from panicking.
                let (Some(row), Some(wr)) = (
                    x.get(o..).and_then(|r| r.first_chunk::<L>()),
                    wc.get(ky * K..).and_then(|r| r.first_chunk::<K>()),
                ) else {
                    return acc;
                };
                for (kx, wt) in wr.iter().enumerate() {
                    unroll_tile!(P, p => mac(&mut acc[p], wt, row[kx + p * S]));
                }
            }
        }
    } else {
        let s = a.g.stride;
        let span = (P - 1) * s + 1;
        for (wt, &off) in w.iter().zip(a.tap_off) {
            let Some(xs) = x.get(base + off..base + off + span) else {
                return acc;
            };
            unroll_tile!(P, p => mac(&mut acc[p], wt, xs[p * s]));
        }
    }
    acc
}

/// `acc[j][k] = fma(w[j][k], x, acc[j][k])` for every panel and lane: independent lanes, one
/// fused multiply-add each (one rounding: see the module's determinism contract).
#[inline(always)]
fn mac<const NP: usize>(acc: &mut [Lanes; NP], w: &[Lanes; NP], x: f32) {
    for (a, w) in acc.iter_mut().zip(w) {
        for k in 0..CONV_LANES {
            a.0[k] = w.0[k].mul_add(x, a.0[k]);
        }
    }
}

/// Writes the first `n` pixels of a tile's accumulators (panels `q..q + NP`) to the CHW output
/// at flat pixel `pix`, skipping padded lanes; with `relu`, as `x < 0 ? 0 : x` (NaN stays NaN).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn store<const P: usize, const NP: usize>(
    acc: &[[Lanes; NP]; P],
    q: usize,
    cout: usize,
    hw: usize,
    pix: usize,
    n: usize,
    relu: bool,
    y: &mut [f32],
) {
    for j in 0..NP {
        for k in 0..CONV_LANES {
            let co = (q + j) * CONV_LANES + k;
            if co >= cout {
                return;
            }
            if let Some(dst) = y.get_mut(co * hw + pix..co * hw + pix + n) {
                for (d, a) in dst.iter_mut().zip(acc) {
                    let v = a[j].0[k];
                    *d = if relu && v < 0.0 { 0.0 } else { v };
                }
            }
        }
    }
}

/// `exp(x)` from +, *, and bit operations only (Cephes `expf` polynomial, ~1 ulp).
///
/// Inputs are clamped to [-87, 88] (outputs stay finite and normal-ish, which is all the
/// activations need); NaN propagates. Branch-free so loops over it vectorize.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // 1.5 * 2^23: adding it rounds to an integer (ties to even) held in the low mantissa bits.
    const SHIFTER: f32 = 12_582_912.0;
    // ln 2 split so that n * C1 is exact for |n| < 2^15 (Cody-Waite reduction).
    const C1: f32 = 0.6933594; // == 0.693359375 = 355/512 exactly
    const C2: f32 = -0.00021219444;
    let x = if x > 88.0 { 88.0 } else { x };
    let x = if x < -87.0 { -87.0 } else { x };
    let k = x * LOG2E + SHIFTER;
    let n = k - SHIFTER;
    let r = x - n * C1 - n * C2;
    let z = r * r;
    let p = ((((0.00019875691 * r + 0.0013981999) * r + 0.008333452) * r + 0.041665796) * r + 0.16666666) * r + 0.5;
    let p = p * z + r + 1.0;
    // 2^n: n sits in the low bits of k's representation (k = 0x4B40_0000 + n as bits).
    let scale = f32::from_bits(k.to_bits().wrapping_sub(0x4B40_0000).wrapping_add(127).wrapping_shl(23));
    p * scale
}

/// Logistic sigmoid `1 / (1 + exp(-x))`.
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `tanh(x)`: odd polynomial for |x| < 0.625 (keeps relative accuracy near 0), otherwise
/// `1 - 2 / (exp(2|x|) + 1)` (Cephes `tanhf`). Both branches are computed and selected, so it
/// vectorizes; the sign is restored with `copysign`.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    let a = x.abs();
    let s = a * a;
    let small = ((((-0.0057049887 * s + 0.020639088) * s - 0.053739715) * s + 0.13331442) * s - 0.3333328) * s * a + a;
    let large = 1.0 - 2.0 / (exp(a + a) + 1.0);
    let t = if a < 0.625 { small } else { large };
    // NaN: `a < 0.625` is false, `large` is NaN, copysign keeps it NaN.
    t.copysign(x)
}

/// ELU: `x` for `x > 0`, else `alpha * (exp(x) - 1)`.
#[inline(always)]
pub fn elu(x: f32, alpha: f32) -> f32 {
    let neg = alpha * (exp(x) - 1.0);
    if x > 0.0 {
        x
    } else {
        neg
    }
}

#[cfg(test)]
// The kernels are checked against std's math on the host; tests never run on the robot.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;
    use hal::XorShift64 as Rng;

    #[test]
    fn exp_matches_std_closely() {
        let mut max_rel = 0.0f64;
        let mut x = -87.0f32;
        while x < 88.0 {
            let got = exp(x) as f64;
            let want = (x as f64).exp();
            max_rel = max_rel.max(((got - want) / want).abs());
            x += 0.0137;
        }
        assert!(max_rel < 3e-7, "max rel err {max_rel}");
        assert!(exp(f32::NAN).is_nan());
        assert!(exp(1000.0).is_finite() && exp(-1000.0) >= 0.0);
    }

    #[test]
    fn tanh_sigmoid_accuracy() {
        let mut x = -20.0f32;
        while x < 20.0 {
            let t = tanh(x) as f64;
            let tw = (x as f64).tanh();
            assert!((t - tw).abs() <= 2e-7 + 3e-7 * tw.abs(), "tanh({x}) {t} vs {tw}");
            let s = sigmoid(x) as f64;
            let sw = 1.0 / (1.0 + (-(x as f64)).exp());
            assert!((s - sw).abs() <= 2e-7, "sigmoid({x}) {s} vs {sw}");
            x += 0.00731;
        }
        assert!(tanh(f32::NAN).is_nan());
        assert_eq!(tanh(1e30), 1.0);
        assert_eq!(tanh(-1e30), -1.0);
        assert_eq!(tanh(0.0), 0.0);
    }

    #[test]
    fn matvec_matches_naive_bitwise() {
        // Same summation order as the naive loop => bit-identical, for ragged shapes too.
        // 37 rows: one pair of panels and an odd one; 100: three full panels and a ragged one.
        for (rows, cols) in [(37, 13), (100, 29), (5, 1)] {
            matvec_case(rows, cols);
        }
    }

    fn matvec_case(rows: usize, cols: usize) {
        let w: Vec<f32> = (0..rows * cols)
            .map(|i| ((i * 7919 % 1000) as f32 - 500.0) * 1e-3)
            .collect();
        let b: Vec<f32> = (0..rows).map(|i| i as f32 * 0.01 - 0.2).collect();
        let x: Vec<f32> = (0..cols).map(|j| (j as f32 * 0.37).sin()).collect();
        let mut m = PackedMatrix::pack(&w, &b, rows, cols);
        for isa in isas() {
            m.set_isa(isa);
            let mut y = vec![0.0; rows];
            m.matvec(&x, &mut y);
            for r in 0..rows {
                let mut acc = b[r];
                for j in 0..cols {
                    acc += w[r * cols + j] * x[j];
                }
                assert_eq!(acc.to_bits(), y[r].to_bits(), "{isa:?} row {r}");
            }
        }
    }

    /// `n` values uniform in [-1, 1).
    fn rand_vec(rng: &mut Rng, n: usize) -> Vec<f32> {
        (0..n).map(|_| rng.signed()).collect()
    }

    /// PyTorch's definition, literally: every tap in (ci, ky, kx) order, zeros for padding.
    fn naive_conv(g: &ConvGeom, w: &[f32], b: &[f32], x: &[f32]) -> Vec<f32> {
        let (ho, wo) = (g.ho(), g.wo());
        let mut y = vec![0.0f32; g.cout * ho * wo];
        for co in 0..g.cout {
            for oy in 0..ho {
                for ox in 0..wo {
                    let mut acc = b[co];
                    for ci in 0..g.cin {
                        for ky in 0..g.kh {
                            for kx in 0..g.kw {
                                let iy = (oy * g.stride + ky) as isize - g.pad as isize;
                                let ix = (ox * g.stride + kx) as isize - g.pad as isize;
                                let inside = iy >= 0 && ix >= 0 && (iy as usize) < g.h && (ix as usize) < g.w;
                                let v = if inside {
                                    x[(ci * g.h + iy as usize) * g.w + ix as usize]
                                } else {
                                    0.0
                                };
                                acc = w[((co * g.cin + ci) * g.kh + ky) * g.kw + kx].mul_add(v, acc);
                            }
                        }
                    }
                    y[(co * ho + oy) * wo + ox] = acc;
                }
            }
        }
        y
    }

    fn isas() -> Vec<Isa> {
        let mut v = vec![Isa::Portable];
        if Isa::detect() != Isa::Portable {
            v.push(Isa::detect());
        } else {
            eprintln!("note: no AVX2 + FMA on this CPU; only the portable conv kernel is tested");
        }
        v
    }

    fn check_conv(g: ConvGeom, rng: &mut Rng) {
        let w = rand_vec(rng, g.cout * g.taps());
        let b = rand_vec(rng, g.cout);
        let mut conv = PackedConv::pack(g, &w, &b, Isa::Portable);
        for _ in 0..2 {
            let x = rand_vec(rng, g.cin * g.h * g.w);
            let want = naive_conv(&g, &w, &b, &x);
            for isa in isas() {
                conv.set_isa(isa);
                for &tile in isa.tiles() {
                    conv.set_tile(tile);
                    let mut y = vec![f32::NAN; conv.output_len()];
                    conv.forward(&x, &mut y);
                    for (i, (a, e)) in y.iter().zip(&want).enumerate() {
                        assert_eq!(
                            a.to_bits(),
                            e.to_bits(),
                            "{g:?} {isa:?} tile {tile} element {i}: {a} vs {e}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn conv_matches_naive_bitwise() {
        // The terrain CNN's layers, then ragged shapes: odd sizes, stride 1/2/3, padding 0/1/2,
        // cin/cout not multiples of the panel width, rectangular kernels and inputs.
        let mut rng = Rng(0x00C0_4F2D);
        for (cin, h, w, cout, k, stride, pad) in [
            (6, 60, 60, 24, 3, 2, 1),
            (24, 30, 30, 48, 3, 2, 1),
            (48, 15, 15, 128, 3, 2, 1),
            (1, 1, 1, 1, 1, 1, 0),
            (3, 7, 5, 5, 3, 1, 1),
            (2, 9, 11, 17, 5, 2, 2),
            (5, 4, 4, 9, 4, 1, 0),
            // 3x3 at stride 1 and 2 (the fixed-size row path) on odd sizes and channel counts,
            // and at stride 3 (the generic path).
            (4, 10, 9, 20, 3, 1, 0),
            (5, 11, 7, 9, 3, 2, 2),
            (2, 3, 17, 41, 3, 2, 1),
            (3, 13, 13, 16, 3, 3, 1),
        ] {
            let g = ConvGeom {
                cin,
                h,
                w,
                cout,
                kh: k,
                kw: k,
                stride,
                pad,
            };
            check_conv(g, &mut rng);
        }
        for _ in 0..60 {
            let kh = 1 + rng.below(4);
            let kw = 1 + rng.below(4);
            let pad = rng.below(kh.max(kw).min(3));
            let h = (kh + rng.below(12)).saturating_sub(2 * pad).max(1);
            let w = (kw + rng.below(12)).saturating_sub(2 * pad).max(1);
            let g = ConvGeom {
                cin: 1 + rng.below(7),
                h: h.max(kh.saturating_sub(2 * pad)),
                w: w.max(kw.saturating_sub(2 * pad)),
                cout: 1 + rng.below(35),
                kh,
                kw,
                stride: 1 + rng.below(3),
                pad,
            };
            check_conv(g, &mut rng);
        }
    }

    #[test]
    fn conv_non_finite_inputs_propagate_identically() {
        let g = ConvGeom {
            cin: 3,
            h: 8,
            w: 8,
            cout: 20,
            kh: 3,
            kw: 3,
            stride: 1,
            pad: 1,
        };
        let mut rng = Rng(5);
        let (w, b) = (rand_vec(&mut rng, g.cout * g.taps()), rand_vec(&mut rng, g.cout));
        let mut x = rand_vec(&mut rng, g.cin * g.h * g.w);
        x[10] = f32::NAN;
        x[100] = f32::INFINITY;
        let want = naive_conv(&g, &w, &b, &x);
        let mut conv = PackedConv::pack(g, &w, &b, Isa::Portable);
        for isa in isas() {
            conv.set_isa(isa);
            let mut y = vec![0.0; conv.output_len()];
            conv.forward(&x, &mut y);
            for (a, e) in y.iter().zip(&want) {
                assert!(a.to_bits() == e.to_bits() || (a.is_nan() && e.is_nan()), "{a} vs {e}");
            }
        }
    }
}
