"""Independent reference: loads a URDF in Pinocchio and in MuJoCo (both refuse non-physical inertias) and prints the
mass of every moving body each of them read, as JSON: {"pinocchio": [...], "mujoco": [...]}. argv: URDF path."""
import json
import sys

import mujoco
import pinocchio


def main() -> None:
    path = sys.argv[1]
    model = pinocchio.buildModelFromUrdf(path)
    pin = [float(model.inertias[j].mass) for j in range(1, model.njoints)]
    mj = mujoco.MjModel.from_xml_path(path)
    masses = [float(mj.body_mass[b]) for b in range(mj.nbody) if mj.body_jntnum[b] > 0]
    json.dump({"pinocchio": pin, "mujoco": masses}, sys.stdout)


if __name__ == "__main__":
    main()
