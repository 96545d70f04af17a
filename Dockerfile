# The trainclimate service: the API, the dashboard and the control loop, with the gateway
# emulator in the same image. Used by docker-compose.yml (PostgreSQL + backend + gateways).
# Two stages: the first builds the wheel (the migrations and the dashboard's files inside the
# package); the image installs that wheel alone, without the source tree.

FROM python:3.11-slim AS wheel
WORKDIR /src
COPY requirements.lock pyproject.toml README.md ./
COPY backend backend
COPY migrations migrations
COPY frontend frontend
RUN pip install --no-cache-dir "$(grep -E '^build==' requirements.lock)" \
    && python -m build --wheel --outdir /dist .

FROM python:3.11-slim
WORKDIR /app
ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    TRAINCLIMATE_HOME=/var/lib/trainclimate

# the pinned dependencies first (a layer that changes only with the lock)
COPY requirements.lock ./
RUN pip install -r requirements.lock

# the package, from the wheel the first stage built
COPY --from=wheel /dist /tmp/dist
RUN pip install --no-deps /tmp/dist/trainclimate-*.whl && rm -rf /tmp/dist

# the default predictor model, fitted once at build time on the simulated fleet dataset (3–6 min)
# into $TRAINCLIMATE_HOME/models, so the backend starts with it (without it, the backend would
# prepare the quick model in the background at its first start, ≈ 1 min under T_rule)
RUN ["trainclimate", "predictor", "default", "--json"]

EXPOSE 8000
# migrations are applied at start; the database comes from TRAINCLIMATE_DATABASE_URL
CMD ["trainclimate", "serve", "--host", "0.0.0.0", "--port", "8000", "--log-level", "info"]
