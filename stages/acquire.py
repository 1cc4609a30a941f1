"""DVC stage: acquire one scene into data/raw/<scene>/ (resumes; reuses what is recorded)."""

import sys

from eskin.acquisition import acquire
from eskin.catalog import RAW_DIR
from eskin.config.acquisition import Acquire, Sim, SimBoard
from eskin.config.base import load_params, sections, validating
from eskin.config.cv import CV
from eskin.config.scenes import Scenes, get_scene
from eskin.errors import RECEIVED_KEPT, run_friendly


def main(scene: str) -> str:
    params = load_params(sections(sim=Sim, sim_board=SimBoard, acquire=Acquire,
                                  scenes=Scenes, cv=CV))
    get_scene(params, scene)
    with validating():  # every scene is checked, but only this one's settings are used
        acquire.check_scenes(params.scenes, params.cv)
    return acquire.acquire(scene, params.scenes[scene], RAW_DIR / scene,
                           acquire=params.acquire, sim=params.sim,
                           board=params.sim_board).summary


if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1])),
                          interrupted=RECEIVED_KEPT))
