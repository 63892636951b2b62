/* AVX2 kernels for Fatrop's equality elimination, swapped into the loaded libfatrop (see solvers/fatrop_kernels.py).
 *
 * Fatrop eliminates each stage's equality rows with a fully pivoted LU of their transposed Jacobian
 * (fatrop_lu_fact_transposed, scalar loops over BLASFEO's panel-major storage) followed by a triangular solve
 * (blasfeo_dtrsm_rlnn, which the AVX2 BLASFEO only has as its reference C code). These are the same two operations
 * for panel-major storage with AVX2/FMA: the same pivots (the first largest |a| in column-major order, as Fatrop's
 * search) and the same eliminations rounded the same way, so the iterates are Fatrop's own (tests/solvers/test_fatrop_direct.py compares both). They reach Fatrop
 * through its procedure linkage table: wbd_fatrop_kernels(1) writes their addresses into libfatrop's GOT slots for
 * those two symbols (found through its dynamic section), (0) puts the saved entries back. */
#include <cmath>
#include <cstdint>
#include <algorithm>
#include <cstring>
#include <vector>
#include <elf.h>
#include <link.h>
#include <sys/mman.h>
#include <unistd.h>
#include <fatrop/linear_algebra/blasfeo_wrapper.hpp>
#include <fatrop/linear_algebra/lu_factorization.hpp>
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#pragma GCC push_options
#pragma GCC optimize("O3", "fp-contract=off") /* BLASFEO's dgead rounds B + (a A) twice: so do we */
void wb_dgemm_nt(int m, int n, int k, double alpha, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sB, int bi,
                 int bj, double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj);
void wb_dsyrk_ln_mn(int m, int n, int k, double alpha, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sB, int bi,
                    int bj, double beta, blasfeo_dmat* sC, int ci, int cj, blasfeo_dmat* sD, int di, int dj);
namespace {
#define WB_EL(A, i, j) ((A)->pA[((i) - ((i) & 3)) * (A)->cn + (j) * 4 + ((i) & 3)])

/* lanes of the panel starting at row p whose rows lie in [first, end) */
inline __m256d wb_row_mask(int first, int end, int p) {
  const __m256i lane = _mm256_setr_epi64x(p, p + 1, p + 2, p + 3);
  const __m256i ge = _mm256_cmpgt_epi64(lane, _mm256_set1_epi64x(first - 1));
  const __m256i lt = _mm256_cmpgt_epi64(_mm256_set1_epi64x(end), lane);
  return _mm256_castsi256_pd(_mm256_and_si256(ge, lt));
}

/* rows [.., n) of the panel at `panel` (rows p .. p + 3): columns i and bc swapped */
inline void wb_swap_columns(double* panel, int p, int n, int i, int bc) {
  if (p + 4 <= n) {
    const __m256d t = _mm256_loadu_pd(panel + i * 4);
    _mm256_storeu_pd(panel + i * 4, _mm256_loadu_pd(panel + bc * 4));
    _mm256_storeu_pd(panel + bc * 4, t);
  } else {
    for (int r = 0; r < n - p; ++r) { const double t = panel[i * 4 + r]; panel[i * 4 + r] = panel[bc * 4 + r]; panel[bc * 4 + r] = t; }
  }
}

/* step i's elimination on one panel: column j (> i) += (-u_j) column i, rows of `rows` only, for the columns j in
   `list` (count of them): those with u_j != 0. The equality Jacobians are sparse (g1: 11 % of the u_j are nonzero);
   a column with u_j = 0 would get + (0 c_i) = +-0 (finite entries), which leaves every value as it is (at most a
   zero's sign changes) */
inline void wb_eliminate(double* panel, int i, const int* list, int count, const double* minus_u, __m256d rows) {
  const __m256d ci = _mm256_and_pd(_mm256_loadu_pd(panel + i * 4), rows);
  for (int t = 0; t < count; t++) {
    const int j = list[t];
    _mm256_storeu_pd(panel + j * 4, _mm256_add_pd(_mm256_loadu_pd(panel + j * 4), _mm256_mul_pd(_mm256_set1_pd(minus_u[j]), ci)));
  }
}

/* step i's row of U (A(i, j) / pivot, j > i), its negatives into minus_u[j], and the j where they are nonzero into
   list; returns how many */
inline int wb_multipliers(blasfeo_dmat* At, int i, int m, double pivot, double* minus_u, int* list) {
  int count = 0;
  for (int j = i + 1; j < m; j++) {
    WB_EL(At, i, j) = WB_EL(At, i, j) / pivot;
    minus_u[j] = -WB_EL(At, i, j);
    list[count] = j;
    count += minus_u[j] != 0.0;
  }
  return count;
}

/* the rows from `eager` on (n rows, m columns, panel stride cn): the column swap and elimination of the LU's steps
   0 .. steps - 1, panel by panel (step i's nonzero u_j: list + i * m, counts[i] of them) */
void wb_eliminate_rest(double* pA, int cn, int eager, int n, int m, int steps, fatrop::PermutationMatrix& Pl,
                       const double* minus_u, const int* list, const int* counts) {
  for (int p = eager; p < n; p += 4) {
    double* const panel = pA + p * cn;
    const __m256d rows = p + 4 > n ? wb_row_mask(p, n, p) : _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    for (int i = 0; i < steps; ++i) {
      if (Pl[i] != i) wb_swap_columns(panel, p, n, i, Pl[i]);
      wb_eliminate(panel, i, list + static_cast<size_t>(i) * m, counts[i], minus_u + static_cast<size_t>(i) * m, rows);
    }
  }
}

/* Fatrop's fatrop_lu_fact_transposed: At (n x m) holds the transposed equality Jacobian; pivots are
   searched in rows < n_max, columns >= i; rank = number of pivots >= tol. The rows the pivot search never reads
   (the panels from n_max on: the states and the right-hand side) get each step's column swap and elimination
   after the last step, panel by panel (each panel stays in L1 through all steps instead of the whole matrix
   streaming through the cache once a step): the same operations on each entry in the same order */
void wb_lu_fact_transposed(const int m, const int n, const int n_max, int& rank, blasfeo_dmat* At,
                           fatrop::PermutationMatrix& Pl, fatrop::PermutationMatrix& Pr, double tol) {
  At->use_dA = 0;
  const int minmn = m < n_max ? m : n_max;
  double* const pA = At->pA;
  const int cn = At->cn;
  const int eager = std::min(n, (n_max + 3) & ~3);  /* rows updated at each step: the pivot search's panels */
  static thread_local std::vector<double> minus_u;  /* step i's -A(i, j), j > i, at step i: minus_u[i * m + j] */
  static thread_local std::vector<int> nonzero;     /* step i's j with minus_u[i * m + j] != 0: nonzero[i * m + t] */
  static thread_local std::vector<int> counts;      /* how many: counts[i] */
  if (static_cast<int>(minus_u.size()) < minmn * m) minus_u.resize(static_cast<size_t>(minmn) * m);
  if (static_cast<int>(nonzero.size()) < minmn * m) nonzero.resize(static_cast<size_t>(minmn) * m);
  if (static_cast<int>(counts.size()) < minmn) counts.resize(static_cast<size_t>(minmn));
  const __m256d abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffffLL));
  const __m256d all = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
  int r = 0;
  for (int i = 0; i < minmn; i++) {
    /* the first largest |A(row, col)| in column-major order (Fatrop: strict >, starting from A(i, i)) */
    const int p0 = i & ~3;
    const __m256d head = wb_row_mask(i, n_max, p0);
    double best = std::fabs(WB_EL(At, i, i));
    int bc = i;
    for (int col = i; col < m; ++col) {
      __m256d acc = _mm256_and_pd(_mm256_and_pd(_mm256_loadu_pd(pA + p0 * cn + col * 4), abs_mask), head);
      for (int p = p0 + 4; p < n_max; p += 4) {
        __m256d v = _mm256_and_pd(_mm256_loadu_pd(pA + p * cn + col * 4), abs_mask);
        if (p + 4 > n_max) v = _mm256_and_pd(v, wb_row_mask(i, n_max, p));
        acc = _mm256_max_pd(v, acc);
      }
      const __m128d h = _mm_max_pd(_mm256_castpd256_pd128(acc), _mm256_extractf128_pd(acc, 1));
      const double col_best = _mm_cvtsd_f64(_mm_max_sd(_mm_unpackhi_pd(h, h), h));
      if (col_best > best) { best = col_best; bc = col; }
    }
    int br = i;
    if (bc != i || !(std::fabs(WB_EL(At, i, i)) >= best))
      for (int row = i; row < n_max; ++row)
        if (std::fabs(WB_EL(At, row, bc)) == best) { br = row; break; }
    if (std::fabs(WB_EL(At, br, bc)) < tol) break;
    if (bc != i)
      for (int p = 0; p < eager; p += 4) wb_swap_columns(pA + p * cn, p, eager, i, bc);
    Pl[i] = bc;
    if (br != i)
      for (int col = 0; col < m; ++col) { double t = WB_EL(At, i, col); WB_EL(At, i, col) = WB_EL(At, br, col); WB_EL(At, br, col) = t; }
    Pr[i] = br;
    const double pivot = WB_EL(At, i, i);
    double* const mu = minus_u.data() + static_cast<size_t>(i) * m;
    int* const list = nonzero.data() + static_cast<size_t>(i) * m;
    const int count = counts[i] = wb_multipliers(At, i, m, pivot, mu, list);
    /* rows i+1 .. eager-1: column j -= L_ij column i */
    for (int p = p0; p < eager; p += 4)
      wb_eliminate(pA + p * cn, i, list, count, mu, p == p0 || p + 4 > n ? wb_row_mask(i + 1, n, p) : all);
    r = i + 1;
  }
  wb_eliminate_rest(pA, cn, eager, n, m, r, Pl, minus_u.data(), nonzero.data(), counts.data());
  rank = r;
}

/* alpha B(b0 .. b0 + 3, col): rows past `rows` zero; whole panels (or two, shifted) as vectors where B's storage
   holds them */
inline __m256d wb_b_rows(const blasfeo_dmat* sB, int b0, int col, int rows, __m256d valpha) {
  const int s = b0 & 3, q = b0 - s, stored = (sB->m + 3) & ~3;
  const double* pq = sB->pA + q * sB->cn + col * 4;
  if (rows == 4 && s == 0) return _mm256_mul_pd(valpha, _mm256_loadu_pd(pq));
  if (rows == 4 && q + 8 <= stored) {
    const __m256d v0 = _mm256_loadu_pd(pq), v1 = _mm256_loadu_pd(pq + 4 * sB->cn);
    __m256d v;
    if (s == 1) v = _mm256_blend_pd(_mm256_permute4x64_pd(v0, 0x39), _mm256_permute4x64_pd(v1, 0x39), 0x8);
    else if (s == 2) v = _mm256_blend_pd(_mm256_permute4x64_pd(v0, 0x4e), _mm256_permute4x64_pd(v1, 0x4e), 0xc);
    else v = _mm256_blend_pd(_mm256_permute4x64_pd(v0, 0x93), _mm256_permute4x64_pd(v1, 0x93), 0xe);
    return _mm256_mul_pd(valpha, v);
  }
  double b[4] = {0.0, 0.0, 0.0, 0.0};
  for (int t = 0; t < rows; ++t) b[t] = WB_EL(sB, b0 + t, col);
  return _mm256_mul_pd(valpha, _mm256_loadu_pd(b));
}

inline __m256d wb_minus(__m256d x, double a, __m256d d) { return _mm256_sub_pd(x, _mm256_mul_pd(_mm256_set1_pd(a), d)); }

/* NP panels of D from row p (all rows whole when NP > 1): BLASFEO's reference dtrsm_rlnn order, the panels' chains
   interleaved */
template <int NP>
void wb_trsm_panels(int m, int n, const __m256d valpha, const blasfeo_dmat* sA, int ai, int aj, const double* dA,
                    const blasfeo_dmat* sB, int bi, int bj, blasfeo_dmat* sD, int di, int dj, int p) {
  double* Dp[NP];
  int rows[NP];
  __m256i store[NP];
  for (int u = 0; u < NP; ++u) {
    Dp[u] = sD->pA + (di + p + 4 * u) * sD->cn;
    rows[u] = m - p - 4 * u < 4 ? m - p - 4 * u : 4;
    store[u] = _mm256_castpd_si256(wb_row_mask(0, rows[u], 0));
  }
  auto put = [&](int u, int col, __m256d v) {
    if (rows[u] == 4) _mm256_storeu_pd(Dp[u] + (dj + col) * 4, v);
    else _mm256_maskstore_pd(Dp[u] + (dj + col) * 4, store[u], v);
  };
  int jj = 0;
  for (; jj < n - 1; jj += 2) {
    const int id = n - jj - 2;
    __m256d d0[NP], d1[NP];
    for (int u = 0; u < NP; ++u) {
      d0[u] = wb_b_rows(sB, bi + p + 4 * u, bj + id, rows[u], valpha);
      d1[u] = wb_b_rows(sB, bi + p + 4 * u, bj + id + 1, rows[u], valpha);
    }
    for (int kk = id + 2; kk < n; kk++) {
      const double a0 = WB_EL(sA, ai + kk, aj + id), a1 = WB_EL(sA, ai + kk, aj + id + 1);
      for (int u = 0; u < NP; ++u) {
        const __m256d dk = _mm256_loadu_pd(Dp[u] + (dj + kk) * 4);
        d0[u] = wb_minus(d0[u], a0, dk);
        d1[u] = wb_minus(d1[u], a1, dk);
      }
    }
    const double a10 = WB_EL(sA, ai + id + 1, aj + id);
    for (int u = 0; u < NP; ++u) {
      d1[u] = _mm256_mul_pd(d1[u], _mm256_set1_pd(dA[id + 1]));
      d0[u] = _mm256_mul_pd(wb_minus(d0[u], a10, d1[u]), _mm256_set1_pd(dA[id]));
      put(u, id, d0[u]);
      put(u, id + 1, d1[u]);
    }
  }
  for (; jj < n; jj++) {
    const int id = n - jj - 1;
    for (int u = 0; u < NP; ++u) {
      __m256d d0 = wb_b_rows(sB, bi + p + 4 * u, bj + id, rows[u], valpha);
      for (int kk = id + 1; kk < n; kk++) d0 = wb_minus(d0, WB_EL(sA, ai + kk, aj + id), _mm256_loadu_pd(Dp[u] + (dj + kk) * 4));
      put(u, id, _mm256_mul_pd(d0, _mm256_set1_pd(dA[id])));
    }
  }
}

/* BLASFEO's dtrsm_rlnn: D = alpha B A^-1, A (n x n) lower triangular, in the order of BLASFEO's reference code
   (the one the AVX2 build runs): columns from the last in pairs, the inverse diagonal kept in A's dA; vectorised
   over four rows of D at a time, two panels interleaved. The fast path needs D's first row at a panel start and D
   apart from A and B (Fatrop's call), otherwise BLASFEO's own routine runs */
void wb_dtrsm_rlnn(int m, int n, double alpha, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sB, int bi, int bj,
                   blasfeo_dmat* sD, int di, int dj) {
  if ((di & 3) != 0 || sD == sB || sD == sA || m <= 0 || n <= 0) {
    blasfeo_dtrsm_rlnn(m, n, alpha, sA, ai, aj, sB, bi, bj, sD, di, dj);
    return;
  }
  sD->use_dA = 0;
  double* dA = sA->dA;
  if (ai == 0 && aj == 0) {
    if (sA->use_dA < n) {
      for (int i = 0; i < n; i++) dA[i] = 1.0 / WB_EL(sA, i, i);
      sA->use_dA = n;
    }
  } else {
    for (int i = 0; i < n; i++) dA[i] = 1.0 / WB_EL(sA, ai + i, aj + i);
    sA->use_dA = 0;
  }
  const __m256d valpha = _mm256_set1_pd(alpha);
  int p = 0;
  for (; p + 8 <= m; p += 8) wb_trsm_panels<2>(m, n, valpha, sA, ai, aj, dA, sB, bi, bj, sD, di, dj, p);
  for (; p < m; p += 4) wb_trsm_panels<1>(m, n, valpha, sA, ai, aj, dA, sB, bi, bj, sD, di, dj, p);
}
/* BLASFEO's dtrtr_l (C's upper triangle = A's lower one transposed, the diagonal too; a copy) on 4x4 blocks in
   registers instead of BLASFEO's element loops over the panels; at panel starts only, else BLASFEO's own */
void wb_dtrtr_l(int m, blasfeo_dmat* sA, int ai, int aj, blasfeo_dmat* sC, int ci, int cj) {
  if ((ai & 3) != 0 || (ci & 3) != 0 || m <= 0) {
    blasfeo_dtrtr_l(m, sA, ai, aj, sC, ci, cj);
    return;
  }
  sC->use_dA = 0;
  const int whole = m & ~3;  /* rows and columns in whole 4x4 blocks */
  for (int J = 0; J < whole; J += 4) {
    const double* a_row = sA->pA + (ai + J) * sA->cn + (aj + J) * 4;  /* the diagonal block */
    double* c_row = sC->pA + (ci + J) * sC->cn + (cj + J) * 4;
    for (int t = 0; t < 4; ++t)
      for (int r = t; r < 4; ++r) c_row[r * 4 + t] = a_row[t * 4 + r];
    for (int I = J + 4; I < whole; I += 4) {
      const double* a = sA->pA + (ai + I) * sA->cn + (aj + J) * 4;
      double* c = sC->pA + (ci + J) * sC->cn + (cj + I) * 4;
      const __m256d a0 = _mm256_loadu_pd(a), a1 = _mm256_loadu_pd(a + 4), a2 = _mm256_loadu_pd(a + 8),
                    a3 = _mm256_loadu_pd(a + 12);
      const __m256d t0 = _mm256_unpacklo_pd(a0, a1), t1 = _mm256_unpackhi_pd(a0, a1);
      const __m256d t2 = _mm256_unpacklo_pd(a2, a3), t3 = _mm256_unpackhi_pd(a2, a3);
      _mm256_storeu_pd(c, _mm256_permute2f128_pd(t0, t2, 0x20));
      _mm256_storeu_pd(c + 4, _mm256_permute2f128_pd(t1, t3, 0x20));
      _mm256_storeu_pd(c + 8, _mm256_permute2f128_pd(t0, t2, 0x31));
      _mm256_storeu_pd(c + 12, _mm256_permute2f128_pd(t1, t3, 0x31));
    }
  }
  for (int i = whole; i < m; ++i)  /* the last rows: element by element */
    for (int j = 0; j <= i; ++j) WB_EL(sC, ci + j, cj + i) = WB_EL(sA, ai + i, aj + j);
}
#undef WB_EL

/* group 1: the equality elimination (same bits as Fatrop's), 2: the sparse products (fatrop_sparse.cpp) */
struct WbSlot { const char* symbol; void* replacement; int group; void** slot; void* saved; };
WbSlot wb_slots[] = {
  {"_ZN6fatrop25fatrop_lu_fact_transposedEiiiRiP12blasfeo_dmatRNS_17PermutationMatrixES4_d",
   reinterpret_cast<void*>(&wb_lu_fact_transposed), 1, nullptr, nullptr},
  {"blasfeo_dtrsm_rlnn", reinterpret_cast<void*>(&wb_dtrsm_rlnn), 1, nullptr, nullptr},
  {"blasfeo_dtrtr_l", reinterpret_cast<void*>(&wb_dtrtr_l), 1, nullptr, nullptr},
  {"blasfeo_dgemm_nt", reinterpret_cast<void*>(&wb_dgemm_nt), 2, nullptr, nullptr},
  {"blasfeo_dsyrk_ln_mn", reinterpret_cast<void*>(&wb_dsyrk_ln_mn), 2, nullptr, nullptr},
};
int wb_slots_found = -1;

/* libfatrop's GOT slots (jump-slot relocations) of the symbols above */
int wb_find_slots(struct dl_phdr_info* info, size_t, void*) {
  if (!info->dlpi_name || !std::strstr(info->dlpi_name, "libfatrop.so")) return 0;
  const ElfW(Addr) base = info->dlpi_addr;
  const ElfW(Dyn)* dyn = nullptr;
  for (int i = 0; i < info->dlpi_phnum; ++i)
    if (info->dlpi_phdr[i].p_type == PT_DYNAMIC) dyn = reinterpret_cast<const ElfW(Dyn)*>(base + info->dlpi_phdr[i].p_vaddr);
  if (!dyn) return 0;
  ElfW(Addr) jmprel = 0, symtab = 0, strtab = 0;
  size_t size = 0;
  for (; dyn->d_tag != DT_NULL; ++dyn) {
    if (dyn->d_tag == DT_JMPREL) jmprel = dyn->d_un.d_ptr;
    else if (dyn->d_tag == DT_PLTRELSZ) size = dyn->d_un.d_val;
    else if (dyn->d_tag == DT_SYMTAB) symtab = dyn->d_un.d_ptr;
    else if (dyn->d_tag == DT_STRTAB) strtab = dyn->d_un.d_ptr;
  }
  if (!jmprel || !symtab || !strtab) return 0;
  /* the loader relocates these entries on most targets; an unrelocated one is an offset below the base */
  if (jmprel < base) jmprel += base;
  if (symtab < base) symtab += base;
  if (strtab < base) strtab += base;
  const ElfW(Rela)* rela = reinterpret_cast<const ElfW(Rela)*>(jmprel);
  const ElfW(Sym)* syms = reinterpret_cast<const ElfW(Sym)*>(symtab);
  int found = 0;
  for (size_t r = 0; r < size / sizeof(ElfW(Rela)); ++r) {
    if (ELF64_R_TYPE(rela[r].r_info) != R_X86_64_JUMP_SLOT) continue;
    const char* name = reinterpret_cast<const char*>(strtab) + syms[ELF64_R_SYM(rela[r].r_info)].st_name;
    for (WbSlot& s : wb_slots)
      if (!s.slot && std::strcmp(name, s.symbol) == 0) { s.slot = reinterpret_cast<void**>(base + rela[r].r_offset); ++found; }
  }
  wb_slots_found = found;
  return 1;
}

bool wb_panel_height_is_4() {
  double memory[256 + 64];
  blasfeo_dmat A;
  const int size = blasfeo_memsize_dmat(8, 8);
  if (size > static_cast<int>(sizeof(memory)) - 64) return false;
  void* aligned = reinterpret_cast<void*>((reinterpret_cast<uintptr_t>(memory) + 63) & ~uintptr_t(63));
  blasfeo_create_dmat(8, 8, &A, aligned);
  std::memset(A.pA, 0, sizeof(double) * 64);
  blasfeo_dgein1(1.0, &A, 5, 1);
  return A.pA[4 * A.cn + 1 * 4 + 1] == 1.0;
}

bool wb_write(void** slot, void* value) {
  const long page = sysconf(_SC_PAGESIZE);
  void* start = reinterpret_cast<void*>(reinterpret_cast<uintptr_t>(slot) & ~uintptr_t(page - 1));
  if (mprotect(start, page, PROT_READ | PROT_WRITE) != 0) return false;
  __atomic_store_n(slot, value, __ATOMIC_SEQ_CST);
  return true;
}
}  // namespace
#pragma GCC pop_options

/* which kernels sit in libfatrop's GOT: 1 all (the equality elimination and the sparse products), 2 the equality
   elimination only, 0 none (Fatrop's and BLASFEO's own). Returns how many slots hold ours now, -1 when this build
   cannot (no AVX2/FMA, BLASFEO panels not 4 rows), -2 when libfatrop or its slots are not found */
extern "C" int wbd_fatrop_kernels(int enable) {
  if (!wb_panel_height_is_4()) return -1;
  if (wb_slots_found < 0) dl_iterate_phdr(wb_find_slots, nullptr);
  if (wb_slots_found <= 0) return -2;
  int active = 0;
  for (WbSlot& s : wb_slots) {
    if (!s.slot) continue;
    if (enable == 1 || (enable == 2 && s.group == 1)) {
      if (*s.slot != s.replacement) {
        s.saved = *s.slot;
        if (!wb_write(s.slot, s.replacement)) return -2;
      }
      ++active;
    } else if (*s.slot == s.replacement && s.saved) {
      wb_write(s.slot, s.saved);
    }
  }
  return active;
}
#else
extern "C" int wbd_fatrop_kernels(int) { return -1; }
#endif
