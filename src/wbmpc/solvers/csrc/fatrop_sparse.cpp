/* Sparsity-aware dgemm_nt and dsyrk_ln_mn for Fatrop's Riccati recursion (swapped into libfatrop's GOT beside the
 * elimination kernels of fatrop_kernels.cpp; see solvers/fatrop_kernels.py).
 *
 * Most of a stage's recursion multiplies by two very sparse matrices: the transposed dynamics Jacobian [B A b]^T
 * (on g1 1-2 nonzeros in each of its 93-123 rows: x+ = x + dt (v, a)), in P's update AL = [B A b]^T P,
 * [B A]^T P [B A] and [B A b]^T H; and the transposed inequality Jacobian, whose columns are mostly box rows of
 * single variables, in its penalty G_i diag(1/d) G_i^T. BLASFEO multiplies their zeros as any other entry. These
 * routines compute the same products (D = beta C + alpha A B^T, for dsyrk the lower part) from the nonzeros only,
 * found by value in each call (an exact zero contributes nothing: no pattern is cached): each entry is a
 * sequential FMA chain over the nonzero terms in k order, as BLASFEO's 12x4 kernel sums (its 4x4 and 8x8 kernels
 * split the chain in two, so a few entries may round differently in the last bit). A product that is not sparse
 * enough, or whose operands are not panel-aligned, runs on BLASFEO itself. */
#include <cstdint>
#include <cstring>
#include <blasfeo.h>
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#pragma GCC push_options
#pragma GCC optimize("O3", "fp-contract=off")
namespace {
#define WB_EL(A, i, j) ((A)->pA[((i) - ((i) & 3)) * (A)->cn + (j) * 4 + ((i) & 3)])
constexpr int kMaxK = 512;     /* longest inner dimension handled here (Fatrop's stages: <= nx + nu) */
constexpr int kMaxN = 512;     /* most columns of D handled here */
constexpr int kMaxRow = 32;    /* most nonzeros in a row of a sparse B */
constexpr double kSparse = 0.5;  /* use a sparse path below this share of the dense work */

/* a pointer the compiler must keep as it is (not re-derive from its thread-local origin) */
template <typename T>
inline T* wb_opaque(T* p) {
  __asm__("" : "+r"(p));
  return p;
}

/* lanes [first, end) of a panel set, the others clear */
inline __m256i wb_lanes(int first, int end) {
  const __m256i lane = _mm256_setr_epi64x(0, 1, 2, 3);
  const __m256i ge = _mm256_cmpgt_epi64(lane, _mm256_set1_epi64x(first - 1));
  const __m256i lt = _mm256_cmpgt_epi64(_mm256_set1_epi64x(end), lane);
  return _mm256_and_si256(ge, lt);
}

/* D's panel (4 rows, one column) from the chain acc: beta C + alpha acc as BLASFEO's scaling (alpha acc, then one
   FMA with beta C; C not read when beta == 0), rows of `store` only */
inline void wb_store(__m256d acc, double alpha, double beta, const double* c, double* d, __m256i store) {
  __m256d out = alpha == 1.0 ? acc : _mm256_mul_pd(_mm256_set1_pd(alpha), acc);
  if (beta != 0.0) out = _mm256_fmadd_pd(_mm256_set1_pd(beta), _mm256_maskload_pd(c, store), out);
  _mm256_maskstore_pd(d, store, out);
}

/* the same for a whole panel (no masked moves: slow on some CPUs) */
inline void wb_store4(__m256d acc, double alpha, double beta, const double* c, double* d) {
  __m256d out = alpha == 1.0 ? acc : _mm256_mul_pd(_mm256_set1_pd(alpha), acc);
  if (beta != 0.0) out = _mm256_fmadd_pd(_mm256_set1_pd(beta), _mm256_loadu_pd(c), out);
  _mm256_storeu_pd(d, out);
}

/* the columns l < k where the panel's rows [0, rows) of A (starting at pa) are not all zero */
inline int wb_panel_support(const double* pa, int k, int rows, int* idx) {
  const __m256d mask = _mm256_castsi256_pd(wb_lanes(0, rows));
  const __m256d zero = _mm256_setzero_pd();
  int count = 0;
  for (int l = 0; l < k; ++l) {
    const __m256d nz = _mm256_and_pd(_mm256_cmp_pd(_mm256_loadu_pd(pa + l * 4), zero, _CMP_NEQ_UQ), mask);
    idx[count] = l;
    count += !_mm256_testz_pd(nz, nz);
  }
  return count;
}

/* D = beta C + alpha A B^T with A's rows sparse: per panel of 4 rows of A, the chains over the columns where the
   panel has a nonzero, eight columns of D at a time. Returns false (nothing written) when not sparse enough */
bool wb_gemm_sparse_a(int m, int n, int k, double alpha, blasfeo_dmat* sA, int aj, blasfeo_dmat* sB, int bi, int bj,
                      double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj) {
  const int panels = (m + 3) / 4;
  static thread_local int tls_idx[kMaxK * 64], tls_counts[64];
  static thread_local const double* tls_row[kMaxN];
  /* the thread's arrays by plain pointers the compiler cannot recompute (wb_opaque): each access of a thread_local
     in a shared library calls __tls_get_addr, and GCC re-derived the addresses in the loops (g1: 5 % of a solve's
     instructions) */
  int* idx = wb_opaque(tls_idx);
  int* counts = wb_opaque(tls_counts);
  const double** row = wb_opaque(tls_row);
  if (panels > 64 || n > kMaxN) return false;
  long work = 0;
  for (int p = 0; p < panels; ++p) {
    const int rows = m - 4 * p < 4 ? m - 4 * p : 4;
    counts[p] = wb_panel_support(sA->pA + 4 * p * sA->cn + aj * 4, k, rows, idx + p * kMaxK);
    work += counts[p];
    if (p >= 3 && work > kSparse * (p + 1) * k) return false;  /* a dense A: given up after 4 panels */
  }
  if (work > kSparse * panels * k) return false;
  for (int j = 0; j < n; ++j) row[j] = &WB_EL(sB, bi + j, bj);  /* B(bi + j, bj + l) = row[j][4 l] */
  for (int p = 0; p < panels; ++p) {
    const int rows = m - 4 * p < 4 ? m - 4 * p : 4;
    const __m256i store = wb_lanes(0, rows);
    const double* pa = sA->pA + 4 * p * sA->cn + aj * 4;
    const double* pc = sC->pA + (ci + 4 * p) * sC->cn + cj * 4;
    double* pd = sD->pA + (di + 4 * p) * sD->cn + dj * 4;
    const int* list = idx + p * kMaxK;
    const int count = counts[p];
    int j = 0;
    for (; j + 8 <= n; j += 8) {  /* eight independent chains */
      __m256d acc[8];
      for (int u = 0; u < 8; ++u) acc[u] = _mm256_setzero_pd();
      for (int t = 0; t < count; ++t) {
        const int l4 = list[t] * 4;
        const __m256d a = _mm256_loadu_pd(pa + l4);
        for (int u = 0; u < 8; ++u) acc[u] = _mm256_fmadd_pd(a, _mm256_broadcast_sd(row[j + u] + l4), acc[u]);
      }
      if (rows == 4)
        for (int u = 0; u < 8; ++u) wb_store4(acc[u], alpha, beta, pc + (j + u) * 4, pd + (j + u) * 4);
      else
        for (int u = 0; u < 8; ++u) wb_store(acc[u], alpha, beta, pc + (j + u) * 4, pd + (j + u) * 4, store);
    }
    for (; j < n; ++j) {
      __m256d acc = _mm256_setzero_pd();
      for (int t = 0; t < count; ++t)
        acc = _mm256_fmadd_pd(_mm256_loadu_pd(pa + list[t] * 4), _mm256_broadcast_sd(row[j] + list[t] * 4), acc);
      wb_store(acc, alpha, beta, pc + j * 4, pd + j * 4, store);
    }
  }
  return true;
}

/* the nonzeros of B's rows bi .. bi + n - 1 in columns bj .. bj + k - 1, row by row in column order (at most
   kMaxRow a row), panel by panel; false when a row has more, or when the first panels hold more than half */
bool wb_row_support(int n, int k, blasfeo_dmat* sB, int bi, int bj, int* count, int (*idx)[kMaxRow],
                    double (*val)[kMaxRow]) {
  const __m256d zero = _mm256_setzero_pd();
  long total = 0;
  for (int j = 0; j < n; ++j) count[j] = 0;
  for (int q = bi & ~3; q < bi + n; q += 4) {
    if (q >= (bi & ~3) + 8 && total > kSparse * (q - bi) * k) return false;  /* a dense B: given up early */
    const int lanes = _mm256_movemask_pd(_mm256_castsi256_pd(wb_lanes(bi - q, bi + n - q)));
    const double* pb = sB->pA + q * sB->cn + bj * 4;
    for (int l = 0; l < k; ++l) {
      int bits = _mm256_movemask_pd(_mm256_cmp_pd(_mm256_loadu_pd(pb + l * 4), zero, _CMP_NEQ_UQ)) & lanes;
      while (bits) {
        const int t = __builtin_ctz(bits), j = q + t - bi;
        bits &= bits - 1;
        if (count[j] == kMaxRow) return false;
        idx[j][count[j]] = l;
        val[j][count[j]++] = pb[l * 4 + t];
        ++total;
      }
    }
  }
  return true;
}

/* D = beta C + alpha A B^T (lower: rows >= the column only) with B's rows sparse: per column j of D, the chain over
   the nonzeros of B's row j, on whole panels of A's columns. Returns false (nothing written) when not sparse enough */
bool wb_product_sparse_b(int m, int n, int k, double alpha, blasfeo_dmat* sA, int aj, blasfeo_dmat* sB, int bi, int bj,
                         double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj, bool lower) {
  static thread_local int tls_idx[kMaxN][kMaxRow], tls_count[kMaxN];
  static thread_local double tls_val[kMaxN][kMaxRow];
  int(*idx)[kMaxRow] = wb_opaque(tls_idx);  /* plain pointers: see wb_gemm_sparse_a */
  int* count = wb_opaque(tls_count);
  double(*val)[kMaxRow] = wb_opaque(tls_val);
  if (n > kMaxN || !wb_row_support(n, k, sB, bi, bj, count, idx, val)) return false;
  long work = 0, dense = 0;
  for (int j = 0; j < n; ++j) {
    const int height = lower ? m - (j & ~3) : m;
    work += (long) count[j] * height;
    dense += (long) k * height;
  }
  if (work > kSparse * dense) return false;
  for (int p = 0; p < m; p += 4) {  /* panel by panel: C and D read and written in their storage order */
    const double* pa = sA->pA + p * sA->cn + aj * 4;
    const double* pc = sC->pA + (ci + p) * sC->cn + cj * 4;
    double* pd = sD->pA + (di + p) * sD->cn + dj * 4;
    const int j_end = lower && p + 4 < n ? p + 4 : n;
    for (int j = 0; j < j_end; ++j) {
      const int* list = idx[j];
      const double* b = val[j];
      __m256d acc = _mm256_setzero_pd();
      for (int t = 0; t < count[j]; ++t) acc = _mm256_fmadd_pd(_mm256_loadu_pd(pa + list[t] * 4), _mm256_set1_pd(b[t]), acc);
      const int r0 = lower ? j : 0;
      if (p >= r0 && p + 4 <= m) wb_store4(acc, alpha, beta, pc + j * 4, pd + j * 4);
      else wb_store(acc, alpha, beta, pc + j * 4, pd + j * 4, wb_lanes(r0 - p, m - p));
    }
  }
  return true;
}

/* the sparse paths need A, C and D panel-aligned at row 0 of a panel, D apart from A and B */
bool wb_aligned(int m, int k, blasfeo_dmat* sA, int ai, blasfeo_dmat* sB, blasfeo_dmat* sC, int ci,
                blasfeo_dmat* sD, int di) {
  return m > 0 && k > 0 && k <= kMaxK && (ai & 3) == 0 && (ci & 3) == 0 && (di & 3) == 0 && ai == 0 && sD != sA &&
         sD != sB;
}
}  // namespace

void wb_dgemm_nt(int m, int n, int k, double alpha, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sB, int bi,
                 int bj, double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj) {
  if (n > 0 && wb_aligned(m, k, sA, ai, sB, sC, ci, sD, di)) {
    sD->use_dA = 0;
    if (wb_gemm_sparse_a(m, n, k, alpha, sA, aj, sB, bi, bj, beta, sC, ci, cj, sD, di, dj)) return;
    if (wb_product_sparse_b(m, n, k, alpha, sA, aj, sB, bi, bj, beta, sC, ci, cj, sD, di, dj, false)) return;
  }
  blasfeo_dgemm_nt(m, n, k, alpha, sA, ai, aj, sB, bi, bj, beta, sC, ci, cj, sD, di, dj);
}

void wb_dsyrk_ln_mn(int m, int n, int k, double alpha, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sB, int bi,
                    int bj, double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj) {
  if (n > 0 && m >= n && wb_aligned(m, k, sA, ai, sB, sC, ci, sD, di)) {
    sD->use_dA = 0;
    if (wb_product_sparse_b(m, n, k, alpha, sA, aj, sB, bi, bj, beta, sC, ci, cj, sD, di, dj, true)) return;
  }
  blasfeo_dsyrk_ln_mn(m, n, k, alpha, sA, ai, aj, sB, bi, bj, beta, sC, ci, cj, sD, di, dj);
}
#undef WB_EL
#pragma GCC pop_options
#endif
