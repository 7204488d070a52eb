// Fused CPU kernels of the tile rasterizer (frng/render/native.py builds and wraps them; frng/render/tiles.py holds
// the PyTorch versions they replace and documents the inputs): front-to-back compositing of every tile, forward and
// backward, and the binning's tile table (bin_tiles, at the end). The module's bindings at the end also expose
// hull.cpp's kernel.
//
// Inputs (all contiguous, CPU; float32 or float64 for the floating ones):
//   params (M+1, 6)  mx, my, conic a, b, c, opacity per instance in absolute pixel coordinates; row M = sentinel
//   f_inst (M+1, D)  features with depth appended
//   ids    (L,)      int64 the tiles' instance rows, each tile's in depth order: tile t's are
//                    ids[starts[t] : starts[t] + counts[t]] (a padded (T, K) table flattened, starts = t K; or the
//                    rows concatenated, starts = exclusive cumulative sum of counts)
//   starts (T,)      int64
//   counts (T,)      int64
//   pix    (P, 2)    tile-local pixel centres
//   origin (T, 6)    tile origins in pixels in columns 0 and 1 (the rest unused)
//
// Per pixel, Gaussian k of its tile has alpha = opacity * exp(-(a dx^2 / 2 + b dx dy + c dy^2 / 2)), dx = x - mx,
// set to zero below max(alpha_min, opacity * cut_factor) and clamped at alpha_max; w_k = alpha_k T_k with
// T_k = prod_{j<k} (1 - alpha_j). Early termination is per pixel: a pixel stops right after the Gaussian that takes
// its transmittance below min_T (that Gaussian is included, so what is left out weighs less than min_T).
//
// The backward walks each pixel back to front from its last contributor, recovering T_k = T_{k+1} / (1 - alpha_k)
// (alpha <= alpha_max < 1 keeps the division safe), as 3DGS does:
//   dL/dalpha_k = T_k g.f_k - (sum_{j>k} w_j g.f_j + g_T T_final) / (1 - alpha_k)
// with g = dL/d(out pixel); zero where alpha was cut or clamped (as frng.render.tiles.composite_backward).
//
// Threads: work is split over W = at::get_num_threads() workers; worker w owns the tiles t with t % W == w and,
// in the backward, its own gradient buffer (worker 0 writes straight into the output). The buffers are summed in
// worker order, row by row. Which worker handles which tile, and the order of every floating-point sum, depends
// only on W: two runs with the same thread count give the same bytes (no atomics).

#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <climits>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

struct Cuts {
  double alpha_min, alpha_max, cut_factor;
};

void check_inputs(const at::Tensor& params, const at::Tensor& f_inst, const at::Tensor& ids, const at::Tensor& starts,
                  const at::Tensor& counts, const at::Tensor& pix, const at::Tensor& origin) {
  TORCH_CHECK(params.device().is_cpu(), "native compositor: CPU tensors only");
  TORCH_CHECK(params.dim() == 2 && params.size(1) == 6, "params must be (M+1, 6)");
  TORCH_CHECK(f_inst.dim() == 2 && f_inst.size(0) == params.size(0), "f_inst must be (M+1, D)");
  TORCH_CHECK(ids.dim() == 1 && ids.scalar_type() == at::kLong, "ids must be (L,) int64");
  TORCH_CHECK(counts.dim() == 1 && counts.scalar_type() == at::kLong, "counts must be (T,) int64");
  TORCH_CHECK(starts.sizes() == counts.sizes() && starts.scalar_type() == at::kLong, "starts must be (T,) int64");
  TORCH_CHECK(pix.dim() == 2 && pix.size(1) == 2, "pix must be (P, 2)");
  TORCH_CHECK(origin.dim() == 2 && origin.size(0) == counts.size(0) && origin.size(1) >= 2, "origin must be (T, 6)");
  for (const at::Tensor* t : {&f_inst, &pix, &origin})
    TORCH_CHECK(t->scalar_type() == params.scalar_type(), "params, f_inst, pix, origin must share one dtype");
  for (const at::Tensor* t : {&params, &f_inst, &ids, &starts, &counts, &pix, &origin})
    TORCH_CHECK(t->is_contiguous() && t->device().is_cpu(), "native compositor: contiguous CPU tensors only");
  const int64_t* st = starts.data_ptr<int64_t>();
  const int64_t* cn = counts.data_ptr<int64_t>();
  for (int64_t t = 0; t < counts.size(0); ++t)
    TORCH_CHECK(st[t] >= 0 && cn[t] >= 0 && cn[t] < INT32_MAX && st[t] + cn[t] <= ids.size(0),
                "tile rows out of the ids' range");
}

// Number of workers: torch's thread count (at most one per tile).
int64_t n_workers(int64_t n_tiles) { return std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n_tiles)); }

// Calls fn(w, t) for every tile t, on worker w = t % W; the W workers run in parallel.
template <typename F>
void for_tiles(int64_t n_tiles, int64_t W, const F& fn) {
  at::parallel_for(0, W, 1, [&](int64_t w0, int64_t w1) {
    for (int64_t w = w0; w < w1; ++w)
      for (int64_t t = w; t < n_tiles; t += W) fn(w, t);
  });
}

// exp for the alphas: float32 uses Cephes' expf (range reduction by ln 2, degree-5 polynomial; ~1 ulp), written
// with plain arithmetic so that the per-tile alpha loop vectorises (glibc's expf does not); float64 uses std::exp.
inline float exp_alpha(float x) {
  x = std::min(std::max(x, -87.0f), 87.0f);
  const float n = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;  // round to nearest (1.5 * 2^23 trick)
  float r = x - n * 0.693359375f;
  r = r - n * -2.12194440e-4f;
  const float z = r * r;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const float y = p * z + r + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;  // 2^n
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return y * scale;
}
inline double exp_alpha(double x) { return std::exp(x); }

// One Gaussian of a tile: (tile-local) mean, conic, opacity, and its cut-offs.
template <typename scalar_t>
struct Splat {
  scalar_t mx, my, a, b, c, op, thr;
};

template <typename scalar_t>
inline Splat<scalar_t> make_splat(const scalar_t* g, scalar_t ox, scalar_t oy, const Cuts& cuts) {
  const scalar_t op = g[5];
  const scalar_t thr = std::max(scalar_t(cuts.alpha_min), op * scalar_t(cuts.cut_factor));
  return {g[0] - ox, g[1] - oy, g[2], g[3], g[4], op, thr};
}

// Alphas of Gaussian s at the pixels q with k < lim[q] (others 0): alpha = op exp(-sigma), 0 below thr (or NaN),
// clamped at alpha_max; dx, dy = pixel - mean. Writes the indices of the nonzero alphas to idx, returns how many.
// One function for forward and backward, compiled without FP contraction (-ffp-contract=off): both take the same
// decisions and see the same bits.
template <typename scalar_t>
inline int64_t splat_alphas(const Splat<scalar_t>& s, const scalar_t* px, const scalar_t* py, const int32_t* lim,
                            int32_t k, int64_t P, scalar_t a_max, scalar_t* alpha, scalar_t* dx, scalar_t* dy,
                            int32_t* idx) {
  for (int64_t q = 0; q < P; ++q) {
    const scalar_t ddx = px[q] - s.mx, ddy = py[q] - s.my;
    const scalar_t sigma = scalar_t(0.5) * s.a * ddx * ddx + s.b * ddx * ddy + scalar_t(0.5) * s.c * ddy * ddy;
    const scalar_t e = s.op * exp_alpha(-sigma);
    const bool keep = (k < lim[q]) & (e >= s.thr);
    alpha[q] = keep ? std::min(e, a_max) : scalar_t(0);
    dx[q] = ddx;
    dy[q] = ddy;
  }
  int64_t n = 0;
  for (int64_t q = 0; q < P; ++q) {
    idx[n] = int32_t(q);
    n += alpha[q] > scalar_t(0);
  }
  return n;
}

// Prefetch the parameter and feature rows of table entry k of a tile (rows are visited in depth order, i.e. at
// random: without this the kernel waits on cache misses). always_inline: GCC 12's mod/ref analysis otherwise sees a
// call without side effects and deletes it.
template <typename scalar_t>
__attribute__((always_inline)) inline void prefetch_rows(const int64_t* row, int64_t k, int64_t n,
                                                         const scalar_t* prm, const scalar_t* fe, int64_t D) {
  if (k < 0 || k >= n) return;
  const int64_t id = row[k];
  __builtin_prefetch(prm + id * 6);
  const char* f = reinterpret_cast<const char*>(fe + id * D);
  for (int64_t off = 0; off < int64_t(D * sizeof(scalar_t)); off += 64) __builtin_prefetch(f + off);
}

constexpr int64_t kAhead = 8;  // table entries prefetched ahead

// x . y summed in a fixed order (8 interleaved partial sums, then the tail, then the partial sums in order): the
// compiler may not reorder a floating-point sum itself, so a plain loop would not vectorise.
template <typename scalar_t>
inline scalar_t dot(const scalar_t* x, const scalar_t* y, int64_t D) {
  constexpr int64_t L = 8;
  scalar_t acc[L] = {};
  int64_t d = 0;
  for (; d + L <= D; d += L)
    for (int64_t j = 0; j < L; ++j) acc[j] += x[d + j] * y[d + j];
  scalar_t s = 0;
  for (; d < D; ++d) s += x[d] * y[d];
  for (int64_t j = 0; j < L; ++j) s += acc[j];
  return s;
}

// Per-worker scratch arrays of one tile (P pixels, D channels).
template <typename scalar_t>
struct Scratch {
  std::vector<scalar_t> px, py, alpha, dx, dy, T, S, gTT, gf;
  std::vector<int32_t> idx, lim;
  Scratch(int64_t P, int64_t D)
      : px(P), py(P), alpha(P), dx(P), dy(P), T(P), S(P), gTT(P), gf(D), idx(P), lim(P) {}
};

// The inputs of composite_forward / composite_backward as raw pointers, and the outputs of the pass at hand.
template <typename scalar_t>
struct Tiles {
  int64_t P, D, ostride;
  const scalar_t *prm, *fe, *pxy, *org;
  const int64_t *ids, *start, *cnt;
  Cuts cuts;
  scalar_t min_T;
  // forward outputs (pre-filled: out 0, T 1, last 0)
  scalar_t *out, *T_out;
  int32_t* last_out;
  // backward inputs: the forward's T and last, the gradients of out and T
  const scalar_t *T_fin, *go, *gT;
  const int32_t* last;
};

// Composite tile t front to back (forward).
template <typename scalar_t>
__attribute__((always_inline)) inline void forward_tile(const Tiles<scalar_t>& A, Scratch<scalar_t>& sc, int64_t t) {
  const int64_t n = A.cnt[t], P = A.P, D = A.D;
  if (n == 0) return;
  const int64_t* row = A.ids + A.start[t];
  scalar_t* T = A.T_out + t * P;
  int32_t* lst = A.last_out + t * P;
  scalar_t* ot = A.out + t * P * D;
  for (int64_t q = 0; q < P; ++q) {
    sc.px[q] = A.pxy[2 * q];
    sc.py[q] = A.pxy[2 * q + 1];
    sc.lim[q] = INT32_MAX;  // set to 0 when the pixel terminates
  }
  int64_t n_live = P;
  const scalar_t ox = A.org[t * A.ostride], oy = A.org[t * A.ostride + 1];
  const scalar_t a_max = scalar_t(A.cuts.alpha_max);
  for (int64_t k = 0; k < std::min(n, kAhead); ++k) prefetch_rows(row, k, n, A.prm, A.fe, D);
  for (int64_t k = 0; k < n && n_live > 0; ++k) {
    prefetch_rows(row, k + kAhead, n, A.prm, A.fe, D);
    const int64_t id = row[k];
    const Splat<scalar_t> s = make_splat(A.prm + id * 6, ox, oy, A.cuts);
    if (!(s.op > 0)) continue;
    const int64_t m = splat_alphas(s, sc.px.data(), sc.py.data(), sc.lim.data(), int32_t(k), P, a_max,
                                   sc.alpha.data(), sc.dx.data(), sc.dy.data(), sc.idx.data());
    const scalar_t* f = A.fe + id * D;
    for (int64_t i = 0; i < m; ++i) {
      const int64_t q = sc.idx[i];
      const scalar_t alpha = sc.alpha[q];
      const scalar_t wq = alpha * T[q];
      scalar_t* o = ot + q * D;
      for (int64_t d = 0; d < D; ++d) o[d] += wq * f[d];
      T[q] *= scalar_t(1) - alpha;
      lst[q] = int32_t(k + 1);
      if (T[q] < A.min_T) {
        sc.lim[q] = 0;
        --n_live;
      }
    }
  }
}

// Walk tile t back to front (backward), adding its gradients to the rows of bp (6 per instance) and bf (D).
template <typename scalar_t>
__attribute__((always_inline)) inline void backward_tile(const Tiles<scalar_t>& A, Scratch<scalar_t>& sc, int64_t t,
                                                         scalar_t* bp, scalar_t* bf) {
  const int64_t P = A.P, D = A.D;
  const int32_t* lst = A.last + t * P;
  int32_t kmax = 0;
  for (int64_t q = 0; q < P; ++q) kmax = std::max(kmax, lst[q]);
  if (kmax == 0) return;
  const int64_t* row = A.ids + A.start[t];
  // per pixel: T (walks back from T_final), S = sum_{j>k} w_j g.f_j, gTT = g_T T_final
  for (int64_t q = 0; q < P; ++q) {
    sc.px[q] = A.pxy[2 * q];
    sc.py[q] = A.pxy[2 * q + 1];
    sc.T[q] = A.T_fin[t * P + q];
    sc.S[q] = 0;
    sc.gTT[q] = A.gT[t * P + q] * A.T_fin[t * P + q];
  }
  scalar_t* T = sc.T.data();
  scalar_t* S = sc.S.data();
  scalar_t* gf = sc.gf.data();
  const scalar_t* go = A.go + t * P * D;
  const scalar_t ox = A.org[t * A.ostride], oy = A.org[t * A.ostride + 1];
  const scalar_t a_max = scalar_t(A.cuts.alpha_max);
  for (int64_t k = kmax - 1; k >= std::max<int64_t>(0, kmax - kAhead); --k)
    prefetch_rows(row, k, kmax, A.prm, A.fe, D);
  for (int64_t k = kmax - 1; k >= 0; --k) {
    prefetch_rows(row, k - kAhead, kmax, A.prm, A.fe, D);
    prefetch_rows(row, k - kAhead / 2, kmax, bp, bf, D);  // the gradient rows
    const int64_t id = row[k];
    const Splat<scalar_t> s = make_splat(A.prm + id * 6, ox, oy, A.cuts);
    if (!(s.op > 0)) continue;
    const int64_t m = splat_alphas(s, sc.px.data(), sc.py.data(), lst, int32_t(k), P, a_max, sc.alpha.data(),
                                   sc.dx.data(), sc.dy.data(), sc.idx.data());
    if (m == 0) continue;
    const scalar_t* f = A.fe + id * D;
    scalar_t s_mx = 0, s_my = 0, s_a = 0, s_b = 0, s_c = 0, s_op = 0;
    std::fill(gf, gf + D, scalar_t(0));
    for (int64_t i = 0; i < m; ++i) {
      const int64_t q = sc.idx[i];
      const scalar_t alpha = sc.alpha[q], dx = sc.dx[q], dy = sc.dy[q];
      const scalar_t one = scalar_t(1) - alpha;
      const scalar_t Tk = T[q] / one;
      T[q] = Tk;
      const scalar_t* gq = go + q * D;
      const scalar_t w_k = alpha * Tk;
      const scalar_t gdotf = dot(gq, f, D);
      for (int64_t d = 0; d < D; ++d) gf[d] += w_k * gq[d];
      const scalar_t d_alpha = Tk * gdotf - (S[q] + sc.gTT[q]) / one;
      S[q] += w_k * gdotf;
      if (alpha >= a_max) continue;  // clamped: no gradient through alpha
      const scalar_t dl = d_alpha * alpha;  // dL/d(log alpha); log alpha = log op - sigma
      s_op += dl / s.op;
      s_mx += dl * (s.a * dx + s.b * dy);
      s_my += dl * (s.b * dx + s.c * dy);
      s_a -= scalar_t(0.5) * dl * dx * dx;
      s_b -= dl * dx * dy;
      s_c -= scalar_t(0.5) * dl * dy * dy;
    }
    scalar_t* dp = bp + id * 6;
    dp[0] += s_mx;
    dp[1] += s_my;
    dp[2] += s_a;
    dp[3] += s_b;
    dp[4] += s_c;
    dp[5] += s_op;
    scalar_t* df = bf + id * D;
    for (int64_t d = 0; d < D; ++d) df[d] += gf[d];
  }
}

// float32 per-tile entry points compiled twice, for AVX2 and for baseline x86-64, the loader picking the one the
// CPU runs (GCC function multi-versioning; no -march=native). FP contraction is off in both, so the two give the
// same bits (checked on the bench scene). float64 (tests, gradcheck) takes the baseline build. -DFRNG_NO_CLONES
// builds the baseline only.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(FRNG_NO_CLONES)
#define FRNG_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define FRNG_CLONES
#endif

FRNG_CLONES void forward_tile_f32(const Tiles<float>& A, Scratch<float>& sc, int64_t t) { forward_tile(A, sc, t); }
FRNG_CLONES void backward_tile_f32(const Tiles<float>& A, Scratch<float>& sc, int64_t t, float* bp, float* bf) {
  backward_tile(A, sc, t, bp, bf);
}
void forward_tile_any(const Tiles<float>& A, Scratch<float>& sc, int64_t t) { forward_tile_f32(A, sc, t); }
void forward_tile_any(const Tiles<double>& A, Scratch<double>& sc, int64_t t) { forward_tile(A, sc, t); }
void backward_tile_any(const Tiles<float>& A, Scratch<float>& sc, int64_t t, float* bp, float* bf) {
  backward_tile_f32(A, sc, t, bp, bf);
}
void backward_tile_any(const Tiles<double>& A, Scratch<double>& sc, int64_t t, double* bp, double* bf) {
  backward_tile(A, sc, t, bp, bf);
}

template <typename scalar_t>
Tiles<scalar_t> make_tiles(const at::Tensor& params, const at::Tensor& f_inst, const at::Tensor& ids,
                           const at::Tensor& starts, const at::Tensor& counts, const at::Tensor& pix, const at::Tensor& origin,
                           const Cuts& cuts) {
  Tiles<scalar_t> A{};
  A.P = pix.size(0);
  A.D = f_inst.size(1);
  A.ostride = origin.size(1);
  A.prm = params.data_ptr<scalar_t>();
  A.fe = f_inst.data_ptr<scalar_t>();
  A.pxy = pix.data_ptr<scalar_t>();
  A.org = origin.data_ptr<scalar_t>();
  A.ids = ids.data_ptr<int64_t>();
  A.start = starts.data_ptr<int64_t>();
  A.cnt = counts.data_ptr<int64_t>();
  A.cuts = cuts;
  return A;
}

template <typename scalar_t>
void forward_impl(Tiles<scalar_t> A, int64_t n_tiles) {
  const int64_t W = n_workers(n_tiles);
  std::vector<Scratch<scalar_t>> scratch(W, Scratch<scalar_t>(A.P, A.D));
  for_tiles(n_tiles, W, [&](int64_t w, int64_t t) { forward_tile_any(A, scratch[w], t); });
}

template <typename scalar_t>
void backward_impl(Tiles<scalar_t> A, int64_t n_tiles, at::Tensor& d_params, at::Tensor& d_f) {
  const int64_t R = d_params.size(0), D = A.D;
  // worker w > 0 accumulates into buffer w - 1; worker 0 straight into the outputs (zero-filled by the caller)
  const int64_t W = n_workers(n_tiles);
  std::vector<at::Tensor> extra_p, extra_f;
  std::vector<scalar_t*> buf_p{d_params.data_ptr<scalar_t>()}, buf_f{d_f.data_ptr<scalar_t>()};
  for (int64_t w = 1; w < W; ++w) {
    extra_p.push_back(at::zeros_like(d_params));
    extra_f.push_back(at::zeros_like(d_f));
    buf_p.push_back(extra_p.back().data_ptr<scalar_t>());
    buf_f.push_back(extra_f.back().data_ptr<scalar_t>());
  }
  std::vector<Scratch<scalar_t>> scratch(W, Scratch<scalar_t>(A.P, D));
  for_tiles(n_tiles, W, [&](int64_t w, int64_t t) { backward_tile_any(A, scratch[w], t, buf_p[w], buf_f[w]); });
  if (W > 1) {  // fixed-order reduction: row r = buffer 0 + buffer 1 + ... + buffer W-1
    at::parallel_for(0, R, 1024, [&](int64_t r0, int64_t r1) {
      for (int64_t r = r0; r < r1; ++r) {
        for (int64_t w = 1; w < W; ++w) {
          for (int64_t j = 0; j < 6; ++j) buf_p[0][r * 6 + j] += buf_p[w][r * 6 + j];
          for (int64_t d = 0; d < D; ++d) buf_f[0][r * D + d] += buf_f[w][r * D + d];
        }
      }
    });
  }
}

std::vector<at::Tensor> composite_forward(const at::Tensor& params, const at::Tensor& f_inst, const at::Tensor& ids,
                                          const at::Tensor& starts, const at::Tensor& counts, const at::Tensor& pix, const at::Tensor& origin,
                                          double min_T, double alpha_min, double alpha_max, double cut_factor) {
  check_inputs(params, f_inst, ids, starts, counts, pix, origin);
  const int64_t n_tiles = counts.size(0), P = pix.size(0), D = f_inst.size(1);
  at::Tensor out = at::zeros({n_tiles, P, D}, params.options());
  at::Tensor T_final = at::ones({n_tiles, P}, params.options());
  at::Tensor last = at::zeros({n_tiles, P}, params.options().dtype(at::kInt));
  const Cuts cuts{alpha_min, alpha_max, cut_factor};
  AT_DISPATCH_FLOATING_TYPES(params.scalar_type(), "frng_composite_forward", [&] {
    Tiles<scalar_t> A = make_tiles<scalar_t>(params, f_inst, ids, starts, counts, pix, origin, cuts);
    A.min_T = scalar_t(min_T);
    A.out = out.data_ptr<scalar_t>();
    A.T_out = T_final.data_ptr<scalar_t>();
    A.last_out = last.data_ptr<int32_t>();
    forward_impl<scalar_t>(A, n_tiles);
  });
  return {out, T_final, last};
}

std::vector<at::Tensor> composite_backward(const at::Tensor& params, const at::Tensor& f_inst,
                                           const at::Tensor& ids, const at::Tensor& starts, const at::Tensor& counts,
                                           const at::Tensor& pix,
                                           const at::Tensor& origin, const at::Tensor& T_final,
                                           const at::Tensor& last, const at::Tensor& g_out, const at::Tensor& g_T,
                                           double alpha_min, double alpha_max, double cut_factor) {
  check_inputs(params, f_inst, ids, starts, counts, pix, origin);
  const int64_t n_tiles = counts.size(0), P = pix.size(0), D = f_inst.size(1);
  TORCH_CHECK(T_final.sizes() == at::IntArrayRef({n_tiles, P}) && T_final.is_contiguous() &&
                  T_final.scalar_type() == params.scalar_type(),
              "T_final must be contiguous (T, P) of the params' dtype");
  TORCH_CHECK(last.sizes() == at::IntArrayRef({n_tiles, P}) && last.is_contiguous() && last.scalar_type() == at::kInt,
              "last must be contiguous (T, P) int32");
  TORCH_CHECK(g_out.sizes() == at::IntArrayRef({n_tiles, P, D}) && g_out.is_contiguous() &&
                  g_out.scalar_type() == params.scalar_type(),
              "g_out must be contiguous (T, P, D) of the params' dtype");
  TORCH_CHECK(g_T.sizes() == at::IntArrayRef({n_tiles, P}) && g_T.is_contiguous() &&
                  g_T.scalar_type() == params.scalar_type(),
              "g_T must be contiguous (T, P) of the params' dtype");
  at::Tensor d_params = at::zeros_like(params);
  at::Tensor d_f = at::zeros_like(f_inst);
  const Cuts cuts{alpha_min, alpha_max, cut_factor};
  AT_DISPATCH_FLOATING_TYPES(params.scalar_type(), "frng_composite_backward", [&] {
    Tiles<scalar_t> A = make_tiles<scalar_t>(params, f_inst, ids, starts, counts, pix, origin, cuts);
    A.T_fin = T_final.data_ptr<scalar_t>();
    A.last = last.data_ptr<int32_t>();
    A.go = g_out.data_ptr<scalar_t>();
    A.gT = g_T.data_ptr<scalar_t>();
    backward_impl<scalar_t>(A, n_tiles, d_params, d_f);
  });
  return {d_params, d_f};
}

// Tile binning (frng.render.tiles.bin_pairs after the depth sort): instance m = inst[j] (j in depth order) covers
// the tiles of its box [floor((mean - extent) / tile), floor((mean + extent) / tile)] (clamped to the grid) of its
// view m / N. A counting sort by tile in depth order gives each tile's instances in depth order: the rows of the
// PyTorch version's padded table (positions j), bit for bit, without sorting the pairs, concatenated rather than
// padded.
template <typename scalar_t>
void bin_impl(const at::Tensor& mean2d, const at::Tensor& extent, const at::Tensor& inst, int64_t N, int64_t TY,
              int64_t TX, int64_t tile, at::Tensor& counts, at::Tensor& ids_out) {
  const int64_t M = inst.size(0), n_tiles = counts.size(0);
  const scalar_t* mp = mean2d.data_ptr<scalar_t>();
  const scalar_t* ep = extent.data_ptr<scalar_t>();
  const int64_t* ip = inst.data_ptr<int64_t>();
  const scalar_t ts = scalar_t(tile);
  std::vector<int64_t> box(5 * M);  // x0, x1, y0, y1, first tile of the view per instance
  auto cell = [](scalar_t v, int64_t hi) {
    const scalar_t c = std::floor(v);
    return c <= scalar_t(0) ? int64_t(0) : (c >= scalar_t(hi) ? hi : int64_t(c));  // clamp(0, hi), as torch
  };
  int64_t* cnt = counts.data_ptr<int64_t>();
  for (int64_t j = 0; j < M; ++j) {
    const int64_t m = ip[j];
    const scalar_t mx = mp[2 * m], my = mp[2 * m + 1], ex = ep[2 * m], ey = ep[2 * m + 1];
    int64_t* b = box.data() + 5 * j;
    b[0] = cell((mx - ex) / ts, TX - 1);
    b[1] = cell((mx + ex) / ts, TX - 1);
    b[2] = cell((my - ey) / ts, TY - 1);
    b[3] = cell((my + ey) / ts, TY - 1);
    b[4] = (m / N) * TY * TX;
    for (int64_t ty = b[2]; ty <= b[3]; ++ty)
      for (int64_t tx = b[0]; tx <= b[1]; ++tx) ++cnt[b[4] + ty * TX + tx];
  }
  std::vector<int64_t> fill(n_tiles);  // next free slot of each tile: starts at the exclusive cumulative sum
  int64_t total = 0;
  for (int64_t t = 0; t < n_tiles; ++t) {
    fill[t] = total;
    total += cnt[t];
  }
  ids_out = at::empty({total}, counts.options());
  int64_t* ids = ids_out.data_ptr<int64_t>();
  for (int64_t j = 0; j < M; ++j) {
    const int64_t* b = box.data() + 5 * j;
    for (int64_t ty = b[2]; ty <= b[3]; ++ty)
      for (int64_t tx = b[0]; tx <= b[1]; ++tx) ids[fill[b[4] + ty * TX + tx]++] = j;
  }
}

std::vector<at::Tensor> bin_tiles(const at::Tensor& mean2d, const at::Tensor& extent, const at::Tensor& inst,
                                  int64_t V, int64_t N, int64_t TY, int64_t TX, int64_t tile) {
  TORCH_CHECK(mean2d.dim() == 2 && mean2d.size(0) == V * N && mean2d.size(1) == 2 && mean2d.is_contiguous() &&
                  mean2d.device().is_cpu(),
              "mean2d must be contiguous CPU (V N, 2)");
  TORCH_CHECK(extent.sizes() == mean2d.sizes() && extent.is_contiguous() &&
                  extent.scalar_type() == mean2d.scalar_type(),
              "extent must be contiguous (V N, 2) of mean2d's dtype");
  TORCH_CHECK(inst.dim() == 1 && inst.is_contiguous() && inst.scalar_type() == at::kLong, "inst must be (M,) int64");
  TORCH_CHECK(TY > 0 && TX > 0 && tile > 0 && V >= 0 && N >= 0, "bad tile grid");
  if (inst.numel()) {
    TORCH_CHECK(inst.min().item<int64_t>() >= 0 && inst.max().item<int64_t>() < V * N, "inst out of range");
  }
  at::Tensor counts = at::zeros({V * TY * TX}, inst.options());
  at::Tensor ids;
  AT_DISPATCH_FLOATING_TYPES(mean2d.scalar_type(), "frng_bin_tiles", [&] {
    bin_impl<scalar_t>(mean2d, extent, inst, N, TY, TX, tile, counts, ids);
  });
  return {ids, counts};
}

}  // namespace

namespace frng {
at::Tensor hull_occupancy(const at::Tensor& alpha, const at::Tensor& A, const at::Tensor& B, const at::Tensor& t,
                          double stop);
}  // namespace frng (hull.cpp)

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("bin_tiles", &bin_tiles,
        "(ids (L,) int64: each tile's instance positions in depth order, tile after tile; counts (T,)) from "
        "mean2d (V N, 2), extent (V N, 2) and the depth-ordered instances inst (M,)");
  m.def("forward", &composite_forward,
        "Composite every tile front to back: (out (T, P, D), T_final (T, P), last (T, P) int32 = 1 + index of each "
        "pixel's last processed entry of its tile's row)");
  m.def("backward", &composite_backward,
        "Gradients (d_params (M+1, 6), d_f_inst (M+1, D)) of composite_forward's outputs");
  m.def("hull_occupancy", &frng::hull_occupancy,
        "Visual-hull occupancy (R, K): per ray sample the minimum over views of the bilinear mask read where it "
        "projects, from masks (V, H, W), A, B (V, R, 3) and distances t (R, K); with a stop level (not NaN) each ray's "
        "samples after the first that reaches it are 0 (hull.cpp)");
}
