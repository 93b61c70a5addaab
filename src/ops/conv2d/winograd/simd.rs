//! The parts the AVX-512 and AVX2 Winograd kernels share, written once and instantiated per
//! register type by [`simd_common`]: lane helpers, the transform rows ([`super::tiles`]'s
//! `winograd_rows`), the input transform and the output transform.

/// Generates, in the invoking kernel module, for the vector type `$v` of `$lanes` f32 lanes and the
/// target feature `$feat`: `mulc`, `fmac`, `add`, `sub`, `bt_rows`, `at_rows`, `input_window::<T>`
/// (`Bᵀ d B` of one window), `input_transform::<T>` (`V` of every tile of a group) and
/// `output_transform::<T>` (`act((Aᵀ M A) + b)` for every tile of a group into its up to `M x M`
/// output pixels), `$lanes` channels at a time. The invoking module provides
/// `load_chunk(p, lanes)` and `store_chunk(p, lanes, v)` for the first `lanes <= $lanes` channels.
macro_rules! simd_common {
    ($feat:literal, $v:ty, $lanes:expr, $load:path, $store:path, $addp:path, $subp:path, $mulp:path,
     $fmaddp:path, $set1:path, $maxp:path, $zero:path) => {
        /// `c · x`, rounded.
        #[inline]
        #[target_feature(enable = $feat)]
        fn mulc(c: f32, x: $v) -> $v {
            $mulp($set1(c), x)
        }

        /// `fma(c, x, a)`.
        #[inline]
        #[target_feature(enable = $feat)]
        fn fmac(c: f32, x: $v, a: $v) -> $v {
            $fmaddp($set1(c), x, a)
        }

        /// `a + b`.
        #[inline]
        #[target_feature(enable = $feat)]
        fn add(a: $v, b: $v) -> $v {
            $addp(a, b)
        }

        /// `a - b`.
        #[inline]
        #[target_feature(enable = $feat)]
        fn sub(a: $v, b: $v) -> $v {
            $subp(a, b)
        }

        $crate::ops::conv2d::winograd::tiles::winograd_rows!(
            #[inline]
            #[target_feature(enable = $feat)]
            $v,
            add,
            sub,
            mulc,
            fmac,
            $zero()
        );

        /// `Bᵀ d B` of one window (`v[i][j]`, rows of the window first, then columns).
        #[inline]
        #[target_feature(enable = $feat)]
        fn input_window<T: Tile>(d: &[[$v; MAX_R]; MAX_R]) -> [[$v; MAX_R]; MAX_R] {
            let zero = $zero();
            let mut e = [[zero; MAX_R]; MAX_R];
            for (r, er) in e.iter_mut().enumerate().take(T::R) {
                *er = bt_rows::<T>(&d[r]);
            }
            let mut v = [[zero; MAX_R]; MAX_R];
            for j in 0..T::R {
                let col: [$v; MAX_R] = std::array::from_fn(|r| e[r][j]);
                for (i, val) in bt_rows::<T>(&col).into_iter().enumerate().take(T::R) {
                    v[i][j] = val;
                }
            }
            v
        }

        /// `V[ξ][t][c] = (Bᵀ d B)[ξ]` for every tile `t` of the group and channel `c`, `$lanes`
        /// channels at a time (`load_chunk` / `store_chunk` for the last, shorter chunk). Rows are
        /// read through row pointers, a row outside the image pointing at `zeros`; columns outside
        /// the image give zero.
        ///
        /// # Safety
        /// As the module's `group`; `v` holds `P · n · c_in` floats, `zeros` `w · c_in` zeros.
        #[target_feature(enable = $feat)]
        unsafe fn input_transform<T: Tile>(
            packed: &PackedWinograd,
            input: &[f32],
            g: Group,
            v: &mut [f32],
            zeros: &[f32],
        ) {
            let geom = packed.geometry();
            let (h, w, c_in) = (geom.h(), geom.w(), geom.c_in());
            debug_assert!(zeros.len() >= w * c_in);
            let vp = v.as_mut_ptr();
            let rows = window_rows::<T>(input, g, (h, w, c_in), zeros);
            for t in 0..g.n {
                let tx = g.tx0 + t;
                for c0 in (0..c_in).step_by($lanes) {
                    let lanes = ($lanes).min(c_in - c0);
                    let mut d = [[$zero(); MAX_R]; MAX_R];
                    for (r, dr) in d.iter_mut().enumerate().take(T::R) {
                        for (j, dk) in dr.iter_mut().enumerate().take(T::R) {
                            let ix = (T::M * tx + j).wrapping_sub(1);
                            if ix < w {
                                // SAFETY: column ix is inside the image and channels c0 .. c0 +
                                // lanes exist; the row pointer is an image row or `zeros` (w c_in
                                // floats).
                                *dk = unsafe { load_chunk(rows[r].add(ix * c_in + c0), lanes) };
                            }
                        }
                    }
                    for (i, vi) in input_window::<T>(&d).iter().enumerate().take(T::R) {
                        for (j, &val) in vi.iter().enumerate().take(T::R) {
                            let at = ((T::R * i + j) * g.n + t) * c_in + c0;
                            // SAFETY: at + lanes <= P n c_in (caller contract).
                            unsafe { store_chunk(vp.add(at), lanes, val) };
                        }
                    }
                }
            }
        }

        /// `act((Aᵀ M A) + b)` (plus the skip value when given) for every tile of the group into
        /// its (up to) `M x M` output pixels, output channels `32 og .. 32 og + 32` (the dot
        /// products in `m` are theirs), stored by the layout.
        ///
        /// # Safety
        /// As the module's `group`; `og < c_out / 32`.
        #[target_feature(enable = $feat)]
        unsafe fn output_transform<T: Tile>(
            packed: &PackedWinograd,
            g: Group,
            activation: Activation,
            m: &[f32],
            out: &mut Rows<'_>,
            og: usize,
        ) {
            let geom = packed.geometry();
            let (h, w, c_out) = (geom.h(), geom.w(), geom.c_out());
            let relu = activation == Activation::Relu;
            let zero = $zero();
            let (dst, skip, layout) = (out.rows.as_mut_ptr(), out.skip.map(<[f32]>::as_ptr), out.layout);
            let n_rows = T::M.min(h - T::M * g.ty);
            for q in 0..SIMD_C_OUT / $lanes {
                let o = og * SIMD_C_OUT + q * $lanes;
                // SAFETY: the bias holds c_out floats, o + lanes <= c_out.
                let b = unsafe { $load(packed.bias().as_ptr().add(o)) };
                for t in 0..g.n {
                    let tx = g.tx0 + t;
                    let mut x = [zero; MAX_POINTS];
                    for (xi, xv) in x.iter_mut().enumerate().take(T::P) {
                        // SAFETY: point ξ's tile t lives at (ξ n + t) 32 + q lanes .. inside `m`.
                        *xv = unsafe { $load(m.as_ptr().add((xi * g.n + t) * SIMD_C_OUT + q * $lanes)) };
                    }
                    let mut s = [[zero; MAX_M]; MAX_R];
                    for (a, sa) in s.iter_mut().enumerate().take(T::R) {
                        let row: [$v; MAX_R] =
                            std::array::from_fn(|k| if k < T::R { x[T::R * a + k] } else { zero });
                        *sa = at_rows::<T>(&row);
                    }
                    for (j, ox) in (T::M * tx..w.min(T::M * tx + T::M)).enumerate() {
                        let col: [$v; MAX_R] = std::array::from_fn(|a| s[a][j]);
                        let y = at_rows::<T>(&col);
                        for (r, &yr) in y.iter().enumerate().take(n_rows) {
                            let mut val = $addp(yr, b);
                            if relu {
                                val = $maxp(val, zero);
                            }
                            let at = layout.offset(w, c_out, r, ox, o);
                            // SAFETY: output row r < n_rows of the tile row, column ox < w, and the
                            // layout keeps a vector inside one parity block (`supports_layout`);
                            // `skip` has the rows' length.
                            unsafe {
                                if let Some(sk) = skip {
                                    val = $addp(val, $load(sk.add(at)));
                                }
                                $store(dst.add(at), val);
                            }
                        }
                    }
                }
            }
        }
    };
}
pub(super) use simd_common;
