"""The stage kinds' Hessian and Jacobian evaluated for several stages at once, one stage per SIMD lane.

A stage kind's generated Hessian is one straight-line block of scalar arithmetic (g1's plain stage: 128k
operations, 1.3 MB of machine code), run once per stage of the kind: g1's 11 plain stages run the same code 11
times per Fatrop iteration. Here CasADi's C of such a function is rewritten statement by statement into GCC vector
arithmetic on `LANES` doubles (`double __attribute__((vector_size(8 * LANES)))`): lane l holds stage l's values, so
one pass through the code evaluates up to `LANES` stages of the kind with the instructions of one. Each lane does the
scalar code's operations in the same order (+, -, *, / are lane-wise IEEE operations, the library functions are
called per lane), so each stage's values are the scalar function's bit for bit where the compiler contracts no
multiply-add differently (none at -O1, which forms no FMAs).

The rewritten function takes LANES pointers per input and output (`arg[i * LANES + l]`) and clears only the lanes'
outputs the caller asks it to (a buffer that holds the function's last outputs has zeros where it writes none); the
function's scalar entry calls it with every lane on its one stage (so covers and single evaluations run the same
machine code). A function
with a statement of another form keeps CasADi's scalar code (the shim then evaluates its stages one by one).
"""

from __future__ import annotations

import re

LANES = 4
_BODY_SIGNATURE = "(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem)"
_VALUE = r"(?:a\d+|-?\d+\.?\d*(?:e[-+]?\d+)?)"  # a work variable or a number

PRELUDE = f"""
/* ---- wbmpc: vector arithmetic over {LANES} stages (solvers/stage_vectors.py) ---- */
#include <string.h>
typedef double wbv __attribute__((vector_size({8 * LANES})));
#define WB_LANES {LANES}
#define WB_C(x) ((wbv){{{", ".join(["(x)"] * LANES)}}})
#define WB_IN(i, k) (arg[WB_LANES * (i)] ? (wbv){{{", ".join(f"arg[WB_LANES * (i) + {l}][k]" for l in range(LANES))}}} \\
                                         : WB_C(0.))
#define WB_OUT(i, k, v) do {{ {" ".join(f"res[WB_LANES * (i) + {l}][k] = (v)[{l}];" for l in range(LANES))} }} while (0)
#define WB_LANE1(f, a) ({{ wbv wb_r_; int wb_l_; for (wb_l_ = 0; wb_l_ < WB_LANES; ++wb_l_) wb_r_[wb_l_] = f((a)[wb_l_]); wb_r_; }})
#define WB_LANE2(e, a, b) ({{ wbv wb_r_; int wb_l_; for (wb_l_ = 0; wb_l_ < WB_LANES; ++wb_l_) {{ \\
  const double x_ = (a)[wb_l_], y_ = (b)[wb_l_]; wb_r_[wb_l_] = (e); }} wb_r_; }})
#define WB_LANE3(a, b, c) ({{ wbv wb_r_; int wb_l_; for (wb_l_ = 0; wb_l_ < WB_LANES; ++wb_l_) \\
  wb_r_[wb_l_] = (a)[wb_l_] ? (b)[wb_l_] : (c)[wb_l_]; wb_r_; }})
static void wb_clear_lanes(casadi_real** res, int i, size_t n, int clear) {{
  int l;
  for (l = 0; l < WB_LANES; ++l)
    if ((clear >> l) & 1) memset(res[WB_LANES * i + l], 0, sizeof(casadi_real) * n);
}}
"""

_RULES = [
    (re.compile(r"  casadi_real (a\d+(?:, a\d+)*);"), lambda m: f"  wbv {m.group(1)};"),
    (re.compile(r"  (a\d+)=arg\[(\d+)\]\? arg\[\2\]\[(\d+)\] : 0;"), lambda m: f"  {m[1]}=WB_IN({m[2]},{m[3]});"),
    (re.compile(r"  res\[(\d+)\]\[(\d+)\]=(a\d+);"), lambda m: f"  WB_OUT({m[1]},{m[2]},{m[3]});"),
    (re.compile(r"  memset\(res\[(\d+)\], 0, sizeof\(casadi_real\) \* (\d+)\);"),
     lambda m: f"  wb_clear_lanes(res, {m[1]}, {m[2]}, clear);"),
    (re.compile(r"  (a\d+)=(-?\d+\.?\d*(?:e[-+]?\d+)?);"), lambda m: f"  {m[1]}=WB_C({m[2]});"),
    (re.compile(r"  (a\d+)=(a\d+);"), lambda m: m[0]),
    (re.compile(rf"  (a\d+)=\((a\d+|{_VALUE})([-+*/])({_VALUE})\);"), lambda m: _binary(m)),
    (re.compile(r"  (a\d+)=\(-(a\d+)\);"), lambda m: m[0]),
    (re.compile(r"  (a\d+)=casadi_sq\((a\d+)\);"), lambda m: f"  {m[1]}=({m[2]}*{m[2]});"),
    (re.compile(r"  (a\d+)=([a-z_][a-z_0-9]*)\((a\d+)\);"), lambda m: f"  {m[1]}=WB_LANE1({m[2]},{m[3]});"),
    (re.compile(r"  (a\d+)=([a-z_][a-z_0-9]*)\((a\d+),(a\d+)\);"),
     lambda m: f"  {m[1]}=WB_LANE2({m[2]}(x_, y_),{m[3]},{m[4]});"),
    (re.compile(r"  (a\d+)=\((a\d+)(<=|>=|<|>|==|!=|&&|\|\|)(a\d+)\);"),
     lambda m: f"  {m[1]}=WB_LANE2(x_ {m[3]} y_,{m[2]},{m[4]});"),
    (re.compile(r"  (a\d+)=\(!(a\d+)\);"), lambda m: f"  {m[1]}=WB_LANE2(!x_,{m[2]},{m[2]});"),
    (re.compile(r"  (a\d+)=\((a\d+)\?(a\d+):0\);"), lambda m: f"  {m[1]}=WB_LANE2(x_ ? y_ : 0,{m[2]},{m[3]});"),
    (re.compile(r"  (a\d+)=\((a\d+)\?(a\d+):(a\d+)\);"), lambda m: f"  {m[1]}=WB_LANE3({m[2]},{m[3]},{m[4]});"),
]


def _binary(m: re.Match) -> str | None:
    """x op y with at least one work variable (vector op scalar broadcasts the number, as GCC defines it)."""
    if not (m[2].startswith("a") or m[4].startswith("a")):
        return None
    return m[0]


def _statement(line: str) -> str | None:
    """One line of a generated body as vector code; None if it is of another form."""
    if not line.strip():
        return line
    for pattern, rewrite in _RULES:
        found = pattern.fullmatch(line)
        if found:
            return rewrite(found)
    return None


def vector_body(body: str) -> str | None:
    """CasADi's body of a scalar function (the lines between its opening brace and its `return 0;`) as vector code,
    or None where a statement is of a form not rewritten here."""
    out = []
    for line in body.split("\n"):
        rewritten = _statement(line)
        if rewritten is None:
            return None
        out.append(rewritten)
    return "\n".join(out)


def vectorize(code: str, names: list[str], n_in: dict[str, int], n_out: dict[str, int]) -> tuple[str, list[str]]:
    """The generated C with each named function (its export calls a static `casadi_f<i>`) also as a vector
    function `<name>_lanes(arg, res)` of LANES stages (whose machine code takes the static function's place and
    section), the static function calling it with every lane on its one stage; and the names rewritten."""
    done = []
    for name in names:
        found = re.search(re.escape(f"int {name}{_BODY_SIGNATURE}") + r"\{\s*return (casadi_f\d+)\(", code)
        if not found:
            continue
        static = found.group(1)
        head = re.search(r"\n([^\n]*)static int " + re.escape(static + _BODY_SIGNATURE) + r" \{\n", code)
        if head is None:
            continue
        start, end = head.end(), code.find("\n  return 0;\n}\n", head.end())
        body = vector_body(code[start:end]) if end > 0 else None
        if body is None:
            continue
        attributes, ni, no = head.group(1), n_in[name], n_out[name]
        attributes += "" if "noinline" in attributes else "__attribute__((noinline)) "
        vector = (f"\n{attributes}static int {static}_lanes(const casadi_real** arg, casadi_real** res, int clear) {{\n"
                  f"{body}\n  return 0;\n}}\n")
        scalar = (f"static int {static}{_BODY_SIGNATURE} {{\n"
                  f"  const casadi_real* lane_arg[{ni * LANES}];\n  casadi_real* lane_res[{max(no, 1) * LANES}];\n"
                  f"  int i, l;\n  for (i = 0; i < {ni}; ++i) for (l = 0; l < WB_LANES; ++l) "
                  f"lane_arg[WB_LANES * i + l] = arg[i];\n"
                  f"  for (i = 0; i < {no}; ++i) for (l = 0; l < WB_LANES; ++l) lane_res[WB_LANES * i + l] = res[i];\n"
                  f"  return {static}_lanes(lane_arg, lane_res, 1);\n}}\n"
                  f"int {name}_lanes(const casadi_real** arg, casadi_real** res, int clear) {{\n"
                  f"  return {static}_lanes(arg, res, clear);\n}}\n")
        code = code[:head.start()] + vector + scalar + code[end + len("\n  return 0;\n}\n"):]
        done.append(name)
    if done:
        marker = code.index("\n", code.index("#define casadi_int")) + 1
        marker = code.index("#endif\n", marker) + len("#endif\n")
        code = code[:marker] + PRELUDE + code[marker:]
    return code, done
