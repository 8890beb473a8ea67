"""ament_python build of piezofin_ros (colcon build / pip install)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "piezofin_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/fins", glob("config/fins/*.yaml")),
        (f"share/{PACKAGE}/config/amplifiers", glob("config/amplifiers/*.yaml")),
        (f"share/{PACKAGE}/config/models", glob("config/models/*.yaml")),
        (f"share/{PACKAGE}/config/bodies", glob("config/bodies/*.yaml")),
        (f"share/{PACKAGE}/config/batteries", glob("config/batteries/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/bags", ["bags/sample_M8528-P1.mcap"]),  # `player -p bag:=bags/sample_...`
    ],
    install_requires=["setuptools", "numpy", "scipy", "pyyaml", "matplotlib"],
    # ray: the benchmarks' and `diagnose --paper`'s tasks on a Ray cluster (piezofin_ros.workers);
    # optional, and without it they run on local worker processes
    extras_require={"test": ["pytest", "hypothesis"], "fast": ["numba"], "ray": ["ray>=2.9"]},
    zip_safe=False,
    maintainer="piezofin_ros developers",
    maintainer_email="dev@piezofin.local",
    description="MFC piezoelectric fin: simulated hardware, thrust estimation, control, MCAP, diagnosis",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "piezofin = piezofin_ros.cli.main:main",
            "sweep = piezofin_ros.cli.main:sweep_main",
            "diagnose = piezofin_ros.cli.main:diagnose_main",
            "identify = piezofin_ros.cli.main:identify_main",
            "fin_sim = piezofin_ros.nodes.entry:fin_sim",
            "fin_sims = piezofin_ros.nodes.entry:fin_sims",
            "thrust_estimator = piezofin_ros.nodes.entry:thrust_estimator",
            "controller = piezofin_ros.nodes.entry:controller",
            "recorder = piezofin_ros.nodes.entry:recorder",
            "player = piezofin_ros.nodes.entry:player",
            "speed_loop = piezofin_ros.nodes.entry:speed_loop",
            "bringup = piezofin_ros.nodes.entry:bringup",
        ],
    },
)
