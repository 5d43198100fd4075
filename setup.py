"""Builds deepcontact._box2d, the one native extension, against Debian's libbox2d, Eigen, libxml2
and zlib.

Everything else about the package lives in setup.cfg.
"""
import glob
import os
import shlex
import subprocess
import sys
import sysconfig

from pybind11.setup_helpers import ParallelCompile, Pybind11Extension, build_ext
from setuptools import find_packages, setup


# pkg-config name: (what it is, Debian's package)
NEEDS = {"box2d": ("Box2D 2.4.1", "libbox2d-dev"), "eigen3": ("Eigen 3, header-only", "libeigen3-dev"),
         "libxml-2.0": ("libxml2 (the step-file reader)", "libxml2-dev"), "zlib": ("zlib", "zlib1g-dev")}


def pkg_config(*args, package="box2d"):
    try:
        out = subprocess.run(["pkg-config", *args, package], check=True,
                             capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        what, debian = NEEDS[package]
        sys.exit(f"error: {what} not found by `pkg-config {package}`; install it with "
                 f"`apt-get install {debian} pkg-config` (or run `make setup`)")
    return shlex.split(out)


LIBRARIES = ("box2d", "libxml-2.0", "zlib")
cflags = [f for p in ("box2d", "eigen3", "libxml-2.0", "zlib") for f in pkg_config("--cflags", package=p)]
box2d_version = pkg_config("--modversion")[0]
ext = Pybind11Extension(
    "deepcontact._box2d",
    sources=[
        # (the longest compiles first, so that the two compilers of a 2-core machine end together)
        "deepcontact/native/solve.cpp",
        "deepcontact/native/module.cpp",
        "deepcontact/native/solver_module.cpp",
        "deepcontact/native/splat.cpp",
        "deepcontact/native/pgs_step.cpp",
        "deepcontact/native/step_read.cpp",
        "deepcontact/native/world.cpp",
        "deepcontact/native/world_loop.cpp",
        "deepcontact/native/step_xml.cpp",
    ],
    # the solver's drivers are headers (compiled in solve.cpp): a change to one must rebuild the module
    depends=sorted(glob.glob("deepcontact/native/*.hpp")),
    include_dirs=[f[2:] for f in cflags if f.startswith("-I")],
    libraries=[f[2:] for p in LIBRARIES for f in pkg_config("--libs", package=p) if f.startswith("-l")],
    # Box2D 2.4.1's own b2_version still says 2.4.0; record the packaged version we built against.
    define_macros=[("DC_BOX2D_VERSION", f'"{box2d_version}"')],
    cxx_std=17,
    # No FMA contraction: the solver must round exactly as Box2D's float32 code does.
    extra_compile_args=["-O2", "-ffp-contract=off"],
)

# Box2D v3 (3.1), from the pyb2d3 wheel's headers and static library, where it is installed (make
# setup installs it): a second engine in the same module (native/world3.cpp). Found without
# importing pyb2d3.
def box2d3():
    import importlib.util
    from pathlib import Path
    spec = importlib.util.find_spec("pyb2d3")
    if spec is None or not spec.submodule_search_locations:
        return None
    site = Path(list(spec.submodule_search_locations)[0]).parent
    header, library = site / "include" / "box2d" / "box2d.h", site / "lib64" / "libbox2d.a"
    return (header, library) if header.is_file() and library.is_file() else None


v3 = box2d3()
if v3 is not None:
    ext.sources.append("deepcontact/native/world3.cpp")
    ext.define_macros += [("DC_HAVE_BOX2D3", "1"), ("DC_BOX2D3_H", f'"{v3[0]}"')]
    ext.extra_objects = [str(v3[1])]

# Every package under deepcontact/ (a new one cannot be forgotten), plus the two folders that
# setup.cfg's package_dir maps into it.
packages = find_packages(include=["deepcontact", "deepcontact.*"]) + ["deepcontact.cli", "deepcontact.schemas"]


def stale(obj, src):
    """Whether an object file must be compiled again: it is older than its source, than any of
    the native headers (no per-file header tracking: any header counts) or than this file (the
    flags). `python3 setup.py build_ext --inplace` after a change to one .cpp compiles that file
    alone, and pip's wheel build after its editable install compiles nothing (BuildExt)."""
    inputs = [src, __file__, *glob.glob("deepcontact/native/*.hpp")]
    return os.stat(obj).st_mtime < max(os.stat(p).st_mtime for p in inputs)


class BuildExt(build_ext):
    """The objects go to one folder whoever builds: pip's editable install and its wheel build
    would each compile in a folder of their own (the editable one temporary), so the wheel the tests
    build after `make setup` compiled the module a second time; now it links what `stale` keeps."""

    def finalize_options(self):
        super().finalize_options()
        # (one per interpreter, platform and pybind11: an object compiled against other headers is
        # not stale by its date, and must not be linked; pip's isolated build of `pip install .`
        # brings the newest pybind11, perhaps not the one make setup installed)
        import pybind11
        here = os.path.dirname(os.path.abspath(__file__))
        self.build_temp = os.path.join(here, "build", f"native.{sysconfig.get_platform()}-{sys.implementation.cache_tag}"
                                                      f"-pybind11-{pybind11.__version__}")
        print(f"building the native module deepcontact._box2d in {self.build_temp} (about a minute on 2 cores "
              "the first time; the files changed since, after)", file=sys.stderr, flush=True)


# The translation units compile side by side (DC_BUILD_JOBS overrides the core count).
ParallelCompile("DC_BUILD_JOBS", needs_recompile=stale).install()
setup(ext_modules=[ext], packages=packages, cmdclass={"build_ext": BuildExt})
