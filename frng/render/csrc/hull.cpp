// The visual hull's occupancy along rays (frng/priors/multiview.py, occupancy(); the PyTorch version beside it is
// the reference): for every sample k of ray r the minimum over the V input views of that view's mask, read
// bilinearly where the sample projects (pixel centres at +0.5, zero outside the image, as grid_sample with
// align_corners=False and zero padding), and 0 where the sample lies behind a camera (z <= 0).
//
// Inputs (contiguous, CPU, float32):
//   alpha (V, H, W)  the masks
//   A, B  (V, R, 3)  each ray's homogeneous image coordinates in each view are A + t B (frng.priors.multiview.
//                    ray_homogeneous): x = (A0 + t B0) / z, y = (A1 + t B1) / z, z = A2 + t B2
//   t     (R, K)     the sample distances
//   stop  a level, or NaN: with a level, a ray stops at its first sample whose occupancy reaches it and its later
//         samples are 0 (the hull's first crossing is all frng.priors.multiview.hull_distance reads, and a sample
//         inside the hull costs a read in every view, one outside it usually one)
// Output: occupancy (R, K) in [0, 1].
//
// A sample stops at the first view whose mask is 0 there (most of a sweep lies outside some view's silhouette),
// which is what makes this faster than the dense PyTorch version; each view's value is computed with the same
// float operations in the same order, so the minimum is the same bytes. Parallel over rays; no reductions across
// threads, so the bytes do not depend on the thread count either.

#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <cmath>
#include <cstdint>
#include <limits>

namespace frng {

namespace {

inline float mask_at(const float* img, int64_t H, int64_t W, int64_t y, int64_t x) {
  return (x >= 0 && x < W && y >= 0 && y < H) ? img[y * W + x] : 0.0f;
}

// bilinear read at pixel coordinates (x, y), pixel centres at +0.5, zero outside: the arithmetic of
// frng.priors.multiview.sample_image (normalised coordinates 2 x / W - 1) and ATen's CPU grid_sample (bilinear,
// zero padding, align_corners=False: unnormalise (g + 1) W / 2 - 0.5, the corners' weights, and their sum as the
// fused multiply-adds ATen's AVX2/AVX512 build makes of it), so that the value is the same float
// (-ffp-contract=off keeps every other product and sum separate, as PyTorch's elementwise kernels do)
inline float bilinear(const float* img, int64_t H, int64_t W, float x, float y) {
  const float gx = (2.0f * x) / static_cast<float>(W) - 1.0f;
  const float gy = (2.0f * y) / static_cast<float>(H) - 1.0f;
  const float ix = (gx + 1.0f) * (static_cast<float>(W) / 2.0f) - 0.5f;
  const float iy = (gy + 1.0f) * (static_cast<float>(H) / 2.0f) - 0.5f;
  // all four corners outside (or NaN): 0, as the zero padding gives
  if (!(ix > -1.0f && ix < static_cast<float>(W) && iy > -1.0f && iy < static_cast<float>(H))) return 0.0f;
  const float fx = std::floor(ix), fy = std::floor(iy);
  const int64_t x0 = static_cast<int64_t>(fx), y0 = static_cast<int64_t>(fy);
  const float w = ix - fx, e = 1.0f - w, n = iy - fy, s = 1.0f - n;
  const float nw = s * e, ne = s * w, sw = n * e, se = n * w;
  const float acc = std::fma(mask_at(img, H, W, y0, x0 + 1), ne, mask_at(img, H, W, y0, x0) * nw);
  return std::fma(mask_at(img, H, W, y0 + 1, x0 + 1), se, std::fma(mask_at(img, H, W, y0 + 1, x0), sw, acc));
}

// compiled for CPUs with FMA (the hardware instruction) and for baseline x86-64 (std::fma in software), the loader
// picking the one the CPU runs; the same bits either way (a fused multiply-add has one rounding)
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(FRNG_NO_CLONES)
#define FRNG_HULL_CLONES __attribute__((target_clones("fma", "default")))
#else
#define FRNG_HULL_CLONES
#endif

FRNG_HULL_CLONES void hull_rays(const float* img, const float* pa, const float* pb, const float* pt, float* out,
                                int64_t V, int64_t H, int64_t W, int64_t R, int64_t K, float stop, int64_t r0,
                                int64_t r1) {
  for (int64_t r = r0; r < r1; ++r) {
    int64_t k = 0;
    for (; k < K; ++k) {
      const float tk = pt[r * K + k];
      float m = V > 0 ? std::numeric_limits<float>::infinity() : 0.0f;
      for (int64_t v = 0; v < V && m > 0.0f; ++v) {
        const float* a = pa + (v * R + r) * 3;
        const float* b = pb + (v * R + r) * 3;
        const float z = a[2] + tk * b[2];
        if (!(z > 0.0f)) {  // behind the camera
          m = 0.0f;
          break;
        }
        const float zs = z < 1e-9f ? 1e-9f : z;
        const float val = bilinear(img + v * H * W, H, W, (a[0] + tk * b[0]) / zs, (a[1] + tk * b[1]) / zs);
        if (val < m) m = val;
      }
      out[r * K + k] = m;
      if (m >= stop) break;  // never with stop NaN
    }
    for (++k; k < K; ++k) out[r * K + k] = 0.0f;
  }
}

}  // namespace

at::Tensor hull_occupancy(const at::Tensor& alpha, const at::Tensor& A, const at::Tensor& B, const at::Tensor& t,
                          double stop) {
  TORCH_CHECK(alpha.dim() == 3 && alpha.is_contiguous() && alpha.scalar_type() == at::kFloat && alpha.device().is_cpu(),
              "alpha must be contiguous CPU float32 (V, H, W)");
  const int64_t V = alpha.size(0), H = alpha.size(1), W = alpha.size(2);
  TORCH_CHECK(t.dim() == 2 && t.is_contiguous() && t.scalar_type() == at::kFloat, "t must be contiguous float32 (R, K)");
  const int64_t R = t.size(0), K = t.size(1);
  for (const at::Tensor* x : {&A, &B}) {
    TORCH_CHECK(x->dim() == 3 && x->size(0) == V && x->size(1) == R && x->size(2) == 3 && x->is_contiguous() &&
                    x->scalar_type() == at::kFloat,
                "A and B must be contiguous float32 (V, R, 3)");
  }
  at::Tensor occ = at::empty({R, K}, t.options());
  const float* img = alpha.data_ptr<float>();
  const float* pa = A.data_ptr<float>();
  const float* pb = B.data_ptr<float>();
  const float* pt = t.data_ptr<float>();
  float* out = occ.data_ptr<float>();
  const float level = static_cast<float>(stop);
  at::parallel_for(0, R, 16, [&](int64_t r0, int64_t r1) { hull_rays(img, pa, pb, pt, out, V, H, W, R, K, level, r0, r1); });
  return occ;
}

}  // namespace frng
