# COLMAP's sparse run through pycolmap (4.x, CPU), as `handheld bench sparse`'s reference:
# feature extraction (one shared SIMPLE_RADIAL camera), exhaustive matching, incremental mapping,
# each timed; the largest model is written as text. Prints one JSON line on stdout.
# Usage: python3 -c SCRIPT IMAGES WORK THREADS
import json, os, sys, time

try:
    import pycolmap
except ImportError as e:
    print(json.dumps({"missing": str(e)}))
    sys.exit(3)
if int(pycolmap.__version__.split(".")[0]) < 4:
    print(json.dumps({"missing": f"pycolmap {pycolmap.__version__} is too old"}))
    sys.exit(3)

images, work, threads = sys.argv[1], sys.argv[2], int(sys.argv[3])
db = os.path.join(work, "database.db")
sparse = os.path.join(work, "sparse")
text = os.path.join(work, "model")
os.makedirs(sparse, exist_ok=True)
os.makedirs(text, exist_ok=True)
cpu = pycolmap.Device.cpu

reader = pycolmap.ImageReaderOptions()
reader.camera_model = "SIMPLE_RADIAL"
extraction = pycolmap.FeatureExtractionOptions()
extraction.num_threads = threads
extraction.use_gpu = False
t0 = time.perf_counter()
pycolmap.extract_features(db, images, camera_mode=pycolmap.CameraMode.SINGLE,
                          reader_options=reader, extraction_options=extraction, device=cpu)
t1 = time.perf_counter()
matching = pycolmap.FeatureMatchingOptions()
matching.num_threads = threads
matching.use_gpu = False
pycolmap.match_exhaustive(db, matching_options=matching, device=cpu)
t2 = time.perf_counter()
mapping = pycolmap.IncrementalPipelineOptions()
mapping.num_threads = threads
models = pycolmap.incremental_mapping(db, images, sparse, options=mapping)
t3 = time.perf_counter()

with pycolmap.Database.open(db) as d:
    total_images = d.num_images()
best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
if best is not None:
    best.write_text(text)
print(json.dumps({
    "version": pycolmap.__version__,
    "extraction_seconds": t1 - t0,
    "matching_seconds": t2 - t1,
    "mapping_seconds": t3 - t2,
    "models": len(models),
    "registered": best.num_reg_images() if best is not None else 0,
    "total_images": total_images,
    "points": best.num_points3D() if best is not None else 0,
    "mean_reprojection_error_px": best.compute_mean_reprojection_error() if best is not None else None,
    "model": text if best is not None else None,
}))
