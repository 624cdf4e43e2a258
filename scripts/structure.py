#!/usr/bin/env python3
"""Structure checks of the workspace: files over a line limit, functions over a line limit, and
import circles between the files of a crate.

    python3 scripts/structure.py                    # every crate; exit 1 when a check fails
    python3 scripts/structure.py --crates pipeline sfm cli --json

An import is a path naming an item of another file of the same crate: `crate::a::B`, `super::B`,
`self::child::f`, or `child::f` for a child module declared in the file. A path is followed through
re-exports (`pub use`) to the file that defines the item, so a facade `mod.rs` that re-exports its
children is not a circle; the re-export itself is an import of the child. Circles are the strongly
connected components of that graph with more than one file.
"""
import argparse
import json
import os
import re
import sys

ITEM_RE = r"(?:fn|struct|enum|trait|type|const|static|union|mod)\s+{}\b|macro_rules!\s*{}\b"


def matching_brace(code, i):
    """The index of the `}` closing the `{` at `i` (or the end of `code`)."""
    depth, j = 0, i
    while j < len(code):
        if code[j] == "{":
            depth += 1
        elif code[j] == "}":
            depth -= 1
            if depth == 0:
                break
        j += 1
    return j


def strip_code(text):
    """Blanks comments, strings and char literals (keeping newlines), so braces and paths are code."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', text[i:i + 10]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'r(#*)"', text[i:])
            end = '"' + m.group(1)
            j = text.find(end, i + len(m.group(0)))
            j = n if j < 0 else j + len(end)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append('"' + re.sub(r"[^\n]", " ", text[i + 1:j - 1]) + '"')
            i = j
        elif c == "'":
            m = re.match(r"'(\\.[^']*|[^\\'])'", text[i:])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


class Crate:
    def __init__(self, root):
        self.root = root
        self.src = os.path.join(root, "src")
        self.files = {}  # module path tuple -> file path
        for dirpath, _, names in os.walk(self.src):
            for name in names:
                if not name.endswith(".rs"):
                    continue
                path = os.path.join(dirpath, name)
                rel = os.path.relpath(path, self.src)[:-3].split(os.sep)
                if rel in (["lib"], ["main"]):
                    mod = ()
                elif rel[-1] == "mod":
                    mod = tuple(rel[:-1])
                else:
                    mod = tuple(rel)
                if mod == () and rel == ["main"] and () in self.files:
                    continue
                self.files[mod] = path
        self._inline = {}
        self.code = {m: strip_code(open(p, encoding="utf-8").read()) for m, p in self.files.items()}
        self.reexports = {m: self._reexports(m) for m in self.files}

    def inline_depth(self, mod, pos):
        """How many inline modules (`mod x { .. }`) of the file enclose `pos`."""
        if mod not in self._inline:
            code = self.code[mod]
            spans = []
            for m in re.finditer(r"\bmod\s+\w+\s*\{", code):
                spans.append((m.start(), matching_brace(code, m.end() - 1)))
            self._inline[mod] = spans
        return sum(1 for a, b in self._inline[mod] if a <= pos <= b)

    def _use_paths(self, mod):
        """Every `use` tree of a file, expanded: (is_pub, [segments], inline depth)."""
        code = self.code[mod]
        for m in re.finditer(r"(\bpub(?:\([^)]*\))?\s+)?\buse\s+([^;]+);", code):
            depth = self.inline_depth(mod, m.start())
            for path in expand_use(m.group(2)):
                yield bool(m.group(1)), path, depth

    def _reexports(self, mod):
        names, globs = {}, []
        for is_pub, path, depth in self._use_paths(mod):
            if not is_pub or depth:
                continue
            absolute = self.absolute(mod, path)
            if absolute is None:
                continue
            if absolute[-1] == "*":
                globs.append(absolute[:-1])
            else:
                alias = path[-1] if not isinstance(path[-1], tuple) else path[-1][1]
                names[alias] = absolute
        return names, globs

    def absolute(self, mod, path, inline=0):
        """Absolute module path of a `use`/expression path seen in `mod` inside `inline` inline
        modules (`mod tests { .. }`), or None (another crate)."""
        path = [p[0] if isinstance(p, tuple) else p for p in path]
        while inline and path and path[0] == "super":
            inline -= 1
            path = path[1:]
            if not path:
                return None
        if not path:
            return None
        head = path[0]
        if head == "crate":
            return tuple(path[1:])
        if head == "self":
            return mod + tuple(path[1:])
        if head == "super":
            base = list(mod)
            while path and path[0] == "super":
                if not base:
                    return None
                base.pop()
                path = path[1:]
            return tuple(base) + tuple(path)
        if mod + (head,) in self.files:
            return mod + tuple(path)
        return None

    def resolve(self, absolute, depth=0):
        """The file module defining what `absolute` names."""
        if depth > 20 or absolute is None:
            return None
        best = ()
        for i in range(len(absolute) + 1):
            if tuple(absolute[:i]) in self.files:
                best = tuple(absolute[:i])
        rest = absolute[len(best):]
        if not rest or rest[0] == "*":
            return best
        name = rest[0]
        if re.search(ITEM_RE.format(re.escape(name), re.escape(name)), self.code[best]):
            return best
        names, globs = self.reexports[best]
        if name in names:
            target = names[name] + tuple(rest[1:])
            return self.resolve(target, depth + 1) or best
        for g in globs:
            target = g + tuple(rest)
            r = self.resolve(target, depth + 1)
            if r is not None and r != g and re.search(
                ITEM_RE.format(re.escape(name), re.escape(name)), self.code[r]
            ):
                return r
        return best

    def edges(self):
        graph = {m: set() for m in self.files}
        for mod, code in self.code.items():
            children = {m[-1] for m in self.files if len(m) == len(mod) + 1 and m[:-1] == mod}
            paths = [(p, d) for _, p, d in self._use_paths(mod)]
            body = re.sub(r"\buse\s+[^;]+;", lambda m: " " * len(m.group(0)), code)
            for m in re.finditer(r"\b((?:crate|super|self)(?:::\w+)+|(?:\w+)(?:::\w+)+)", body):
                segs = m.group(1).split("::")
                if segs[0] in ("crate", "super", "self") or segs[0] in children:
                    paths.append((segs, self.inline_depth(mod, m.start())))
            for path, depth in paths:
                target = self.resolve(self.absolute(mod, path, depth))
                if target is not None and target != mod:
                    graph[mod].add(target)
        return graph


def expand_use(tree):
    """`a::{b, c::{d as e}}` -> [[a, b], [a, c, (d, e)]]."""
    tree = re.sub(r"\s+", "", tree)

    def parse(s):
        out = []
        depth, start = 0, 0
        parts = []
        for i, ch in enumerate(s):
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append(s[start:i])
                start = i + 1
        parts.append(s[start:])
        for part in parts:
            if not part:
                continue
            brace = part.find("{")
            if brace >= 0 and part.endswith("}"):
                prefix = [x for x in part[:brace].split("::") if x]
                for sub in parse(part[brace + 1:-1]):
                    out.append(prefix + sub)
            else:
                segs = part.split("::")
                last = segs[-1]
                if "as" in last and re.match(r"^\w+as\w+$", last):
                    # `aasb` after whitespace removal: recover `a as b` from the original spacing is
                    # lost; handled by the caller's raw regex below.
                    pass
                out.append(segs)
        return out

    # Keep `x as y` recognisable after the whitespace is gone.
    tree_sp = re.sub(r"\s+as\s+", "@", re.sub(r"\s*([{},:])\s*", r"\1", tree))
    result = []
    for path in parse(tree_sp):
        if path and "@" in path[-1]:
            a, b = path[-1].split("@", 1)
            path = path[:-1] + [(a, b)]
        if path and path[-1] == "self":
            path = path[:-1]
        result.append(path)
    return result


def sccs(graph):
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in graph:
        if v not in index:
            visit(v)
    return out


def long_functions(path, limit):
    code = strip_code(open(path, encoding="utf-8").read())
    lines = code.split("\n")
    out = []
    for m in re.finditer(r"\bfn\s+(\w+)", code):
        # The body starts at the first `{` after the signature (skip declarations ending in `;`).
        i = m.end()
        depth_paren = 0
        while i < len(code):
            ch = code[i]
            if ch in "(<[":
                depth_paren += 1
            elif ch in ")>]":
                depth_paren -= 1
            elif ch == ";" and depth_paren <= 0:
                i = -1
                break
            elif ch == "{" and depth_paren <= 0:
                break
            i += 1
        if i < 0 or i >= len(code):
            continue
        j = matching_brace(code, i)
        start = code.count("\n", 0, m.start()) + 1
        end = code.count("\n", 0, j) + 1
        if end - start + 1 > limit:
            out.append((m.group(1), start, end - start + 1))
    del lines
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    ap.add_argument("--crates", nargs="*", help="crate folders under crates/ (default: all)")
    ap.add_argument("--max-file-lines", type=int, default=600)
    ap.add_argument("--max-fn-lines", type=int, default=150)
    ap.add_argument("--files", nargs="*", help="check function length only in these files")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    crates_dir = os.path.join(a.root, "crates")
    names = a.crates or sorted(os.listdir(crates_dir))
    report = {"long_files": [], "long_functions": [], "circles": {}}
    for name in names:
        root = os.path.join(crates_dir, name)
        for dirpath, _, files in os.walk(root):
            if "/target" in dirpath:
                continue
            for f in files:
                if f.endswith(".rs") or f.endswith(".js"):
                    p = os.path.join(dirpath, f)
                    n = sum(1 for _ in open(p, encoding="utf-8"))
                    rel = os.path.relpath(p, a.root)
                    if n > a.max_file_lines:
                        report["long_files"].append([rel, n])
                    if f.endswith(".rs") and (not a.files or rel in a.files):
                        for fn, line, length in long_functions(p, a.max_fn_lines):
                            report["long_functions"].append([f"{rel}:{line}", fn, length])
        if os.path.isdir(os.path.join(root, "src")):
            crate = Crate(root)
            circles = sccs(crate.edges())
            if circles:
                report["circles"][name] = [
                    sorted(os.path.relpath(crate.files[m], a.root) for m in c) for c in circles
                ]
    if a.json:
        print(json.dumps(report, indent=1))
    else:
        for rel, n in report["long_files"]:
            print(f"file over {a.max_file_lines} lines: {rel} ({n})")
        for where, fn, n in report["long_functions"]:
            print(f"function over {a.max_fn_lines} lines: {where} {fn} ({n})")
        for name, cs in report["circles"].items():
            for c in cs:
                print(f"import circle in {name}: {' <-> '.join(c)}")
        print(
            f"{len(report['long_files'])} long files, {len(report['long_functions'])} long functions, "
            f"{sum(len(c) for c in report['circles'].values())} import circles"
        )
    failed = report["long_files"] or report["long_functions"] or report["circles"]
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
