//! The parts the AVX-512 and AVX2 Winograd kernels share, written once and instantiated per
//! register type by [`simd_common`]: lane helpers, the transform rows ([`super::tiles`]'s
//! `winograd_rows`) and the output transform.

/// Generates, in the invoking kernel module, for the vector type `$v` of `$lanes` f32 lanes and the
/// target feature `$feat`: `mulc`, `fmac`, `add`, `sub`, `bt_rows`, `at_rows`, `input_window::<T>`
/// (`Bᵀ d B` of one window) and `output_transform::<T>` (`act((Aᵀ M A) + b)` for every tile of a
/// group into its up to `M x M` output pixels, `$lanes` channels at a time).
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

        $crate::nn::conv2d::winograd::tiles::winograd_rows!(
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

        /// `act((Aᵀ M A) + b)` for every tile of the group into its (up to) `M x M` output pixels.
        ///
        /// # Safety
        /// As the module's `group`.
        #[target_feature(enable = $feat)]
        unsafe fn output_transform<T: Tile>(
            packed: &PackedWinograd,
            g: Group,
            activation: Activation,
            m: &[f32],
            rows: &mut [f32],
        ) {
            let geom = packed.geometry();
            let (h, w) = (geom.h(), geom.w());
            let relu = activation == Activation::Relu;
            let zero = $zero();
            let out = rows.as_mut_ptr();
            let n_rows = T::M.min(h - T::M * g.ty);
            for q in 0..SIMD_C_OUT / $lanes {
                // SAFETY: the bias holds 32 floats.
                let b = unsafe { $load(packed.bias().as_ptr().add(q * $lanes)) };
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
                            // SAFETY: output row r < n_rows of the tile row, column ox < w.
                            unsafe { $store(out.add((r * w + ox) * SIMD_C_OUT + q * $lanes), val) };
                        }
                    }
                }
            }
        }
    };
}
pub(super) use simd_common;
