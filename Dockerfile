# One image for every lpc service; compose.yaml picks the module per container.
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends libusb-1.0-0 && \
    rm -rf /var/lib/apt/lists/*
WORKDIR /opt/lpc
COPY pyproject.toml README.md ./
COPY lpc_core ./lpc_core
COPY schemas ./schemas
COPY services ./services
RUN pip install --no-cache-dir .
COPY deploy ./deploy
USER 1000:1000
ENTRYPOINT ["python", "-m"]
