"""A command's -o, read from its arguments as click reads them: the one rule by which a fenced
command's output is found (to be claimed, staged and published: contest/job.py) and the paths a
plug-in's sandbox may never be given (contest/grants.py)."""


def output_argument(args):
    """(index of the -o/--output value in args or None, the text before the path in that argument,
    the path or None, whether --overwrite is given) of a command's arguments, read as click reads
    them: the last -o wins, nothing after --."""
    where, prefix, path, overwrite, k = None, "", None, False, 0
    while k < len(args):
        a = args[k]
        if a == "--":
            break
        if a == "--output" and k + 1 < len(args):
            where, prefix, path = k + 1, "", args[k + 1]
            k += 2
            continue
        cluster = a[1:] if a.startswith("-") and not a.startswith("--") else ""
        if a.startswith("--output="):
            where, prefix, path = k, "--output=", a[len("--output="):]
        elif "o" in cluster and all(c.isalpha() for c in cluster[:cluster.index("o")]):   # (-o PATH, -oPATH, -qo PATH: click's short options)
            cut = cluster.index("o") + 2
            if cut < len(a):
                where, prefix, path = k, a[:cut], a[cut:]
            elif k + 1 < len(args):
                where, prefix, path = k + 1, "", args[k + 1]
                k += 1
        elif a == "--overwrite":
            overwrite = True
        k += 1
    return where, prefix, (path if path not in (None, "", "-") else None), overwrite
