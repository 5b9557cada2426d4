"""Auto-commissioning's job timeout: an overdue job is cancelled (as an operator's cancel), not left running.

The simulated cell's real composition; its simulated operator answers nothing, so the first job (camera) waits
at its first prompt until ``job_timeout_s`` runs out. The REST API is the judge of what is left behind.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config

from cellctl.commissioning.auto import CommissioningFailed, commission_missing


async def test_an_overdue_job_is_cancelled_naming_the_timeout_and_start_is_free_again(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="none")) as service, api_client(service) as client:
        with pytest.raises(CommissioningFailed) as failed:
            await commission_missing(service.jobs, service.orchestrator.machine, actor="test", source="test", job_timeout_s=1.0)
        assert "job_timeout_s" in str(failed.value) and "1 s" in str(failed.value), failed.value
        (job,) = (await client.get("/jobs")).json()
        job = (await client.get(f"/jobs/{job['id']}")).json()
        # Ended as a cancel ends a job: recorded, the reason names the timeout and what sets it; nothing left open.
        assert job["state"] == "cancelled" and not job["running"] and job["prompt"] is None, job
        assert "1 s" in job["error"] and "job_timeout_s" in job["error"], job["error"]
        audit = await service.store.audit_entries(limit=500)
        assert any(a.action == "job.cancel" and a.params.get("job_id") == job["id"] for a in audit), audit
        status = (await client.get("/status")).json()
        assert status["job"] is None, status
        # Start is no longer held back by the job.
        assert await _command(client, "reset") == "IDLE"
        r = await client.post("/commands/start", headers=AUTH)
        assert r.status_code == 200, r.text
