# companion image for a Raspberry Pi / Jetson class board (linux/amd64 and linux/arm64).
#   docker buildx build --platform linux/arm64,linux/amd64 -t companion:latest .
#   docker run --rm -it --network host \
#     -v "$PWD/params:/params:ro" --device /dev/ttyAMA0 --device /dev/video0 \
#     companion:latest fly --params /params/my_vehicle.toml
# Both stages use the same Debian-based Python image, so wheels built in the first run in the second.

FROM python:3.11-slim-bookworm AS build
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY companion ./companion
COPY sitl ./sitl
COPY firmware ./firmware
COPY lab ./lab
COPY plugins ./plugins
COPY params ./params
RUN python -m venv /opt/companion \
    && /opt/companion/bin/pip install --upgrade "pip>=24" \
    && /opt/companion/bin/pip install .

FROM python:3.11-slim-bookworm AS runtime
# libgl/glib are not needed by the headless OpenCV wheel; v4l-utils helps diagnose cameras.
RUN apt-get update \
    && apt-get install -y --no-install-recommends v4l-utils=1.22.* \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --system --create-home --uid 10001 --groups dialout,video companion
COPY --from=build /opt/companion /opt/companion
ENV PATH=/opt/companion/bin:$PATH PYTHONUNBUFFERED=1 MPLBACKEND=Agg
USER 10001
WORKDIR /home/companion
VOLUME ["/params", "/home/companion/runs"]
ENTRYPOINT ["companion"]
CMD ["--help"]
