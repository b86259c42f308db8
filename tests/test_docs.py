"""The API reference builds from the docstrings (docs/build_api.py, pdoc), as CI builds it."""
import importlib.util
import pathlib
import warnings

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_the_api_reference_builds_with_a_page_per_module(tmp_path):
    """Every module of jaxflex, jaxflex.optimize and jaxflex.experiments gets a page, and the pages
    carry the docstrings (units included): a module that fails to import, or a docstring lost,
    fails the build or this check."""
    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    api = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(api)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")         # pdoc's notes on annotations it cannot resolve
        index = api.build(tmp_path)
    assert index.is_file()
    pages = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.html")}
    expected = {name.replace(".", "/") + ".html" for name in api.modules()}
    assert expected <= pages, sorted(expected - pages)
    for must in ("jaxflex/robot.html", "jaxflex/optimize/study.html", "jaxflex/experiments/cli.html",
                 "jaxflex/robot_files.html"):
        assert must in pages
    robot = (tmp_path / "jaxflex" / "robot.html").read_text()
    assert "make_robot" in robot and "Young" in robot and "[kg m^2]" in robot
