# One image for every node: the project installed into a slim Python. Nodes in separate
# containers find each other through the shared graph directory (ipc sockets on a volume).
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md LICENSE constraints.txt ./
COPY src ./src
COPY launch ./launch
COPY scenes ./scenes
COPY models ./models
COPY tests/data ./tests/data
# constraints.txt pins every version, so two builds install the same. The graph directory and
# the run directory are created here, owned by the user the nodes run as, mode 0700: a named
# volume mounted on /graph starts as a copy of this directory (owner and mode included), so the
# nodes do not meet a root-owned graph directory (which they would refuse, docs/graph.md).
RUN pip install --no-cache-dir -c constraints.txt -e '.[sim]' && useradd -m slip \
    && mkdir -m 0700 /graph && mkdir -m 0755 /runs && chown slip:slip /graph /runs
USER slip
ENV SLIP_GRAPH_DIR=/graph
# The simulator's compiled kernels (numba, cache=True) are cached beside their source, which the
# node user cannot write here (/app/src is root's), so numba caches them in ~/.cache/numba
# instead. Building one rig here compiles and caches every kernel in the image: no container
# compiles them at start-up (seconds a real-time rig_sim would spend before its first period).
RUN python -c "from incipient_slip.sim import Rig, load_scene; Rig(load_scene('paper'), 'pla', 0)"
