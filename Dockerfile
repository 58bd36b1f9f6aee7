# companion image for a Raspberry Pi / Jetson class board (linux/amd64 and linux/arm64).
#   docker buildx build --platform linux/arm64,linux/amd64 -t companion:latest .
#   docker run --rm -it --network host \
#     -v "$PWD/params:/params:ro" --device /dev/ttyAMA0 --device /dev/video0 \
#     companion:latest fly --params /params/my_vehicle.toml
# Every stage uses the same Debian bookworm Python base, so wheels installed in the first run in the
# others. BASE_IMAGE: the public python:3.11-slim-bookworm by default, or any bookworm root with
# python3 and python3-venv (tools/docker/build.py builds one from Debian's packages with mmdebstrap
# and builds this file with buildah); only `python3` is used, which both have.
# pip's index: PIP_INDEX_URL; behind a TLS-inspecting proxy, the CA bundle as the build secret
# `pip_cert` (--secret id=pip_cert,src=FILE), used only while pip runs and not kept in any layer.
# The fast tier in the image: --target test, then run it (docs/flying.md#on-the-companion-computer-docker).
ARG BASE_IMAGE=python:3.11-slim-bookworm

FROM ${BASE_IMAGE} AS build
ARG PIP_INDEX_URL=https://pypi.org/simple
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY companion ./companion
COPY sitl ./sitl
COPY firmware ./firmware
COPY lab ./lab
COPY plugins ./plugins
COPY params ./params
RUN --mount=type=secret,id=pip_cert \
    if [ -s /run/secrets/pip_cert ]; then export PIP_CERT=/run/secrets/pip_cert; fi \
    && python3 -m venv /opt/companion \
    && /opt/companion/bin/pip install --upgrade "pip>=24" \
    && /opt/companion/bin/pip install .

FROM ${BASE_IMAGE} AS system
# libgl/glib are not needed by the headless OpenCV wheel; v4l-utils helps diagnose cameras.
RUN apt-get update \
    && apt-get install -y --no-install-recommends v4l-utils=1.22.* \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --system --create-home --uid 10001 --groups dialout,video companion
COPY --from=build /opt/companion /opt/companion
ENV PATH=/opt/companion/bin:$PATH PYTHONUNBUFFERED=1 MPLBACKEND=Agg

# The fast tier against the image's own environment (its venv, its user): the checkout's tests and
# the test extras on top of the runtime's files. `--target test`; not part of the default image.
FROM system AS test
ARG PIP_INDEX_URL=https://pypi.org/simple
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY --chown=10001:10001 . .
RUN --mount=type=secret,id=pip_cert \
    if [ -s /run/secrets/pip_cert ]; then export PIP_CERT=/run/secrets/pip_cert; fi \
    && /opt/companion/bin/pip install ".[test]"
USER 10001
ENTRYPOINT ["python3", "-m", "pytest"]
CMD ["-q", "-p", "no:cacheprovider"]

FROM system AS runtime
USER 10001
WORKDIR /home/companion
VOLUME ["/params", "/home/companion/runs"]
ENTRYPOINT ["companion"]
CMD ["--help"]
