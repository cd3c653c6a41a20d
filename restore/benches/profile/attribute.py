#!/usr/bin/env python3
"""Share of a restorer training step by phase, network operation and leaf kernel, from
`perf script -F tid,ip,sym` of a run recorded with `--call-graph dwarf` (see profile.sh).

Forward samples are named by the innermost `restore::net` function on their stack; backward
samples by the burn-autodiff node being differentiated (`conv2d`, `float_matmul`, ...), since
a backward stack no longer holds the layer that made the node. The second rayon thread's
stolen jobs carry no caller: each is shared among the operations whose own samples end in the
same leaf symbol. Samples that build the training pairs (aberration, the Wiener bank) or
validate are counted apart from the step.
"""
import collections
import re
import sys


def read(path):
    samples, cur = [], None
    for line in open(path, errors="replace"):
        if not line.strip():
            continue
        if not line.startswith("\t"):
            cur = []
            samples.append(cur)
        else:
            parts = line.strip().split(None, 1)
            sym = parts[1] if len(parts) > 1 else "?"
            cur.append(re.sub(r"::h[0-9a-f]{16}", "", sym))
    return samples


def leaf(st):
    f = st[0] if st else "?"
    if re.search(r"clear_page|page_fault|folio|memset|memcpy|mi_|alloc|munmap|madvise|free", f):
        return "memory: page zeroing, allocation, copies"
    if re.search(r"gemm|matmul", f):
        return "matrix products (gemm)"
    if "conv" in f:
        return "convolution loops"
    if re.search(r"rayon|crossbeam|sched|futex|spin|yield|park", f):
        return "thread hand-offs and waits"
    if re.search(r"erf|exp|tanh", f):
        return "erf, exp"
    return "element-wise, reductions, layout copies"


def phase_op(st):
    if any(f.startswith("aberration::") or "restore::data" in f or "restore::family" in f for f in st):
        return "pairs", "building training pairs"
    if any("restore::train::validate" in f for f in st):
        return "validation", "validation"
    if any("burn_optim" in f for f in st):
        return "AdamW", "AdamW"
    if any("AutodiffClient>::backward" in f for f in st):
        for f in st:
            m = re.search(r">>::([a-z0-9_]+)::[A-Za-z0-9]+ as burn_autodiff::ops::backward::Backward", f)
            if m:
                return "backward", m.group(1)
            m = re.search(r"<restore::net::([a-z_]+)::[A-Za-z0-9]+ as burn_autodiff::ops::backward::Backward", f)
            if m:
                return "backward", f"{m.group(1)} (hand-written)"
        # A hand-written backward's parallel jobs carry its kernel but not the node.
        for f in st:
            m = re.search(r"<burn_flex::backend::Flex as restore::net::([a-z_]+)::[A-Za-z]+Ops>", f)
            if m:
                return "backward", f"{m.group(1)} (hand-written)"
        if any("Gradients::register" in f or "broadcast_shape" in f for f in st):
            return "backward", "gradient bookkeeping"
        # Element-wise nodes (slices, chunks, scalar products) whose closures are inlined.
        return "backward", "other element-wise nodes"
    # The second thread's share of a hand-written backward has no autodiff frame (and its
    # stack may be cut short): its innermost kernel is one of the backward pass (a `_grad`
    # or `backward` function, or window_train's strips, whose forward runs window_direct's).
    for f in st:
        m = re.search(r"restore::net::([a-z_]+)::([A-Za-z0-9_]+)", f)
        if m:
            if m.group(1) == "window_train" or re.search(r"_grad|backward", m.group(2)):
                return "backward", f"{m.group(1)} (hand-written)"
            break
    for f in st:
        m = re.match(r"<?restore::net::([a-z_]+)::([A-Za-z_]+(?:::[A-Za-z_]+)?)", f)
        if m and "RestorerNet::forward" not in f:
            return "forward", f"{m.group(1)}::{m.group(2)}"
    if any("RestorerNet::forward" in f for f in st):
        return "forward", "net (top level)"
    if any("time_train_step" in f or "restore::train::train" in f for f in st):
        return "step", "other"
    return "stolen", None


def main():
    samples = read(sys.argv[1])
    tagged = [(phase_op(st), st) for st in samples]
    step = {"forward", "backward", "AdamW", "step"}
    by_leaf = collections.defaultdict(collections.Counter)
    est = collections.Counter()
    apart = collections.Counter()
    for (p, o), st in tagged:
        if p in step:
            by_leaf[st[0] if st else "?"][(p, o)] += 1
            est[(p, o)] += 1
        elif p != "stolen":
            apart[o] += 1
    unmatched = 0
    for (p, _), st in tagged:
        if p != "stolen":
            continue
        c = by_leaf.get(st[0] if st else "?")
        if not c:
            unmatched += 1
            continue
        t = sum(c.values())
        for key, v in c.items():
            est[key] += v / t
    total = sum(est.values()) + unmatched
    print(f"{len(samples)} samples; apart from the step: "
          + ", ".join(f"{k} {100 * v / len(samples):.1f} %" for k, v in apart.items()))
    print("| phase | operation | share of the step |")
    print("|---|---|---:|")
    for (p, o), v in est.most_common():
        if 100 * v / total >= 0.5:
            print(f"| {p} | {o} | {100 * v / total:.1f} % |")
    print(f"| stolen jobs with no match | | {100 * unmatched / total:.1f} % |")
    phases = collections.Counter()
    for (p, _), v in est.items():
        phases[p] += v
    print("phases: " + ", ".join(f"{p} {100 * v / total:.1f} %" for p, v in phases.most_common()))
    leaves = collections.Counter(leaf(st) for (p, _), st in tagged if p in step or p == "stolen")
    t = sum(leaves.values())
    print("leaf kernels: " + ", ".join(f"{k} {100 * v / t:.1f} %" for k, v in leaves.most_common()))


if __name__ == "__main__":
    main()
