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
RUN pip install --no-cache-dir -c constraints.txt -e . && useradd -m slip \
    && mkdir -m 0700 /graph && mkdir -m 0755 /runs && chown slip:slip /graph /runs
USER slip
ENV SLIP_GRAPH_DIR=/graph
