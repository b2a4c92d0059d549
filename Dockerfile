# One image for every node: the project installed into a slim Python. Nodes in separate
# containers find each other through the shared graph directory (ipc sockets on a volume).
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md LICENSE ./
COPY src ./src
COPY launch ./launch
COPY scenes ./scenes
COPY models ./models
COPY tests/data ./tests/data
RUN pip install --no-cache-dir -e . && useradd -m slip
USER slip
ENV SLIP_GRAPH_DIR=/graph
