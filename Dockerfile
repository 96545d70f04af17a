# The trainclimate service: the API, the dashboard and the control loop, with the gateway
# emulator in the same image. Used by docker-compose.yml (PostgreSQL + backend + gateways).
FROM python:3.11-slim

WORKDIR /app
ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    TRAINCLIMATE_HOME=/var/lib/trainclimate

# the pinned dependencies first (a layer that changes only with the lock)
COPY requirements.lock pyproject.toml README.md ./
RUN pip install -r requirements.lock

COPY backend backend
COPY migrations migrations
COPY frontend frontend
RUN pip install --no-deps --no-build-isolation -e .

# the default predictor model, fitted once at build time on the simulated fleet dataset (3–6 min)
# into $TRAINCLIMATE_HOME/models, so the backend starts with it (without it, the backend would
# prepare the quick model in the background at its first start, ≈ 1 min under T_rule)
RUN ["trainclimate", "predictor", "default", "--json"]

EXPOSE 8000
# migrations are applied at start; the database comes from TRAINCLIMATE_DATABASE_URL
CMD ["trainclimate", "serve", "--host", "0.0.0.0", "--port", "8000", "--log-level", "info"]
