#!/usr/bin/env bash
exec "${HANDHELD:-target/release/handheld}" --json bench sparse --images "${1:-../shared/datasets/fountain-P11}/images" --gt "${1:-../shared/datasets/fountain-P11}" --colmap "${@:2}"
